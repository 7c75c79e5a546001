"""Projector patterns of any codec, and the virtual rig's camera images of any codec.

Two things live here:

* :func:`codec_patterns`: the projector images of a codec (what a user projects), uint8,
  ``(frames, projector_height, projector_width)``, each pattern sampled at the centres of the
  projector pixels (``x = j``).
* :func:`render_codec`: the camera images of a codec, given for every camera pixel the TRUE
  projector coordinates ``u`` (column) and ``v`` (row) of the surface point it sees. The
  projector is modelled as continuous (no pixel quantisation): frame ``f`` lights the point
  with the ideal pattern value ``E_f(x)`` at ``x = u`` (u-axis frames) or ``x = v`` (v-axis
  frames), ``E = G_sigma * pattern^gamma`` (``pattern^(gamma/g)`` for a codec pre-compensated
  for gamma ``g``), a Gaussian blur of ``sigma`` projector units
  along the coded axis (square waves and gray bits are rendered as steps, then blurred).
  White frames emit 1, black frames 0 (frames the codec does not use: 0 too). The camera
  sees ``I = albedo (ambient + gain E)`` (fractions of full scale), area-averaged over
  ``supersample x supersample`` sub-samples, blurred by a Gaussian of ``camera_defocus_px``,
  plus seeded Gaussian noise of ``noise_grey`` grey levels, rounded and clipped to the bit
  depth (values above full scale saturate). These options are
  :class:`~metrology.core.simulate.SimulationOptions` fields; its
  ``projector_defocus_codes`` becomes the blur ``8 * projector_defocus_codes`` projector
  pixels (8 px per code: the built-in gcps-v1 codec's 128 codes across 1024 px; the
  realistic preset's 0.15 codes are 1.2 px), unless ``projector_blur_px`` is given.
  ``square`` and ``smoothing_codes`` are not used: the codec says which waveform each
  sequence has.

The virtual rig's one entry, :func:`metrology.core.simulate.render_capture`, gives these true
coordinates for any geometric model.

A noisy render keeps its noise-free frames (keyed by the coordinates' and reflectance's SHA-1, the
codec and the options but the seed; at most :data:`CLEAN_CACHE_BYTES`), and every render keeps its
blurred-pattern tables (:data:`TABLE_CACHE_BYTES`): the renders of a Monte Carlo over noise seeds
then only draw their noise, with images identical to those rendered with nothing kept.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import threading
from collections import OrderedDict
from collections.abc import Hashable, Iterable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from metrology.core.codecs.gray import gray_digits
from metrology.core.codecs.model import Codec, GrayCode, PhaseSequence

if TYPE_CHECKING:  # imported where used: metrology.core.simulate imports this module
    from metrology.core.simulate.options import SimulationOptions

FloatArray = npt.NDArray[np.float64]

PIXELS_PER_CODE = 8.0
"""Projector pixels per light code of the built-in gcps-v1 codec (1024 px, 128 codes): converts
:class:`SimulationOptions` ``projector_defocus_codes`` to projector pixels (the realistic preset's
0.15 codes are 1.2 projector px)."""


@dataclass(frozen=True)
class FrameRole:
    """What one frame shows: ``kind`` in white, black, unused, phase, gray.

    For ``phase``: ``axis``, ``sequence`` (the :class:`PhaseSequence`) and ``step`` k.
    For ``gray``: ``axis``, ``gray`` (the :class:`GrayCode`), ``bit`` (0 = least significant)
    and ``inverse`` (True for the bit's inverse frame).
    """

    kind: str
    axis: str = ""
    sequence: PhaseSequence | None = None
    step: int = 0
    gray: GrayCode | None = None
    bit: int = 0
    inverse: bool = False


def frame_roles(codec: Codec) -> list[FrameRole]:
    """The role of every frame of ``codec``, in frame order."""
    roles = [FrameRole("unused") for _ in range(codec.n_frames)]
    for f in codec.white:
        roles[f] = FrameRole("white")
    for f in codec.black:
        roles[f] = FrameRole("black")
    for axis_name, axis in codec.axes.items():
        for seq in axis.phase:
            for k, f in enumerate(seq.frames):
                roles[f] = FrameRole("phase", axis=axis_name, sequence=seq, step=k)
        g = axis.gray
        if g is not None:
            for i, f in enumerate(g.frames):
                bit = g.bits - 1 - i if g.order == "msb_first" else i
                roles[f] = FrameRole("gray", axis=axis_name, gray=g, bit=bit)
                if g.inverse_frames is not None:
                    roles[g.inverse_frames[i]] = FrameRole("gray", axis=axis_name, gray=g, bit=bit, inverse=True)
    return roles


def pattern_value(role: FrameRole, x: npt.ArrayLike) -> FloatArray:
    """Ideal (unblurred) pattern value in [0, 1] of a frame at projector coordinates ``x``.

    Phase: ``0.5 + 0.5 cos(2 pi (x - origin) / period + 2 pi shift k / N)``, or for a square
    waveform 1 where that cosine is >= 0, else 0. Gray bit b of word
    ``n = clip(floor((x - origin) / word), 0, levels**bits - 1)``: ``(g >> b) & 1`` with
    ``g = n ^ (n >> 1)``, complemented when the code is ``inverted`` and again for an inverse
    frame; with ``levels`` L > 2 the grey level ``d / (L - 1)`` of the base-L gray digit d of
    place value ``L**b`` (:func:`metrology.core.codecs.gray.gray_digits`). White 1, black and
    unused 0.
    """
    x = np.asarray(x, dtype=np.float64)
    if role.kind == "white":
        return np.ones_like(x)
    if role.kind in ("black", "unused"):
        return np.zeros_like(x)
    if role.kind == "phase":
        seq = role.sequence
        assert seq is not None
        if seq.waveform == "square":
            c = np.cos(2 * np.pi * (x - seq.origin) / seq.period + 2 * np.pi * seq.shift * role.step / seq.steps)
            return (c >= 0).astype(np.float64)
        return _sine(seq, role.step, _sine_angle(seq, x), 1.0)
    g = role.gray
    assert g is not None
    with np.errstate(invalid="ignore"):
        n = np.floor((np.nan_to_num(x) - g.origin) / g.word)
    words = np.clip(n, 0, g.words - 1).astype(np.int64)
    if g.levels != 2:
        # digit of place value L**bit: column bits - 1 - bit of the MSB-first digits; level d / (L - 1)
        digit = gray_digits(words, g.levels, g.bits)[..., g.bits - 1 - role.bit]
        return digit.astype(np.float64) / (g.levels - 1)
    bit = ((words ^ (words >> 1)) >> role.bit) & 1
    flip = int(g.inverted) ^ int(role.inverse)
    return (bit ^ flip).astype(np.float64)


def _emitted(role: FrameRole, x: FloatArray, sigma: float, gamma: float) -> FloatArray:
    """``E = G_sigma * pattern^gamma`` at ``x`` (finite values), sigma in projector units."""
    if sigma <= 0 or role.kind in ("white", "black", "unused"):
        value = pattern_value(role, x)
        return value if gamma == 1.0 else value**gamma
    if role.kind == "phase" and role.sequence is not None and role.sequence.waveform == "sine" and gamma == 1.0:
        return _sine(role.sequence, role.step, _sine_angle(role.sequence, x), _sine_damping(role.sequence, sigma))
    # tabulate the stepped pattern on a fine grid (cell means of 8 sub-samples), blur, interpolate
    if x.size == 0:
        return np.zeros_like(x)
    smallest = role.gray.word if role.gray is not None else (role.sequence.period if role.sequence else 1.0)
    step = min(1.0 / 64.0, smallest / 256.0, sigma / 8.0)
    pad = 8.0 * sigma + 2 * step
    lo, hi = float(x.min()) - pad, float(x.max()) + pad
    n = math.ceil((hi - lo) / step) + 1
    if n > 2**24:
        raise ValueError(f"projector blur table too large ({n} samples); reduce the coordinate range or the blur")
    from metrology.core.simulate.kernels import interp_uniform

    out = np.empty(x.shape)  # np.interp(x, lo + np.arange(n) * step, table), bit for bit
    interp_uniform(
        np.ascontiguousarray(x, dtype=np.float64).ravel(),
        lo,
        step,
        _blurred_table(role, lo, step, n, sigma, gamma),
        out.reshape(-1),
    )
    return out


def _sine_angle(seq: PhaseSequence, x: FloatArray) -> FloatArray:
    """The phase of a sinusoidal sequence's step 0 at ``x``: ``2 pi (x - origin) / period`` (a new array)."""
    angle = x - seq.origin
    angle *= 2 * np.pi
    angle /= seq.period
    return angle


def _sine_damping(seq: PhaseSequence, sigma: float) -> float:
    """The factor ``exp(-2 pi^2 sigma^2 / P^2)`` by which a Gaussian blur of ``sigma`` scales a sinusoid."""
    return math.exp(-2 * math.pi**2 * sigma**2 / seq.period**2)


def _sine(seq: PhaseSequence, step: int, angle: FloatArray, damping: float) -> FloatArray:
    """``0.5 + 0.5 damping cos(angle + 2 pi shift step / N)`` of a sinusoidal sequence's step ``step``,
    ``angle`` from :func:`_sine_angle` (a new array; in-place passes, the bits of the expression)."""
    wave = angle + 2 * np.pi * seq.shift * step / seq.steps
    np.cos(wave, out=wave)
    wave *= 0.5 * damping
    wave += 0.5
    return wave


class _KeptArrays:
    """Read-only arrays by key, at most ``max_bytes`` of them, the least recently used dropped first;
    an array larger than a quarter of the bound is not kept. Thread-safe."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self._entries: OrderedDict[Hashable, FloatArray] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def get(self, key: Hashable) -> FloatArray | None:
        with self._lock:
            kept = self._entries.get(key)
            if kept is not None:
                self._entries.move_to_end(key)
            return kept

    def fits(self, nbytes: int) -> bool:
        return nbytes <= self.max_bytes // 4

    def keep(self, key: Hashable, array: FloatArray) -> None:
        """Keep ``array`` (made read-only) under ``key`` if it :meth:`fits`."""
        array.setflags(write=False)
        if not self.fits(array.nbytes):
            return
        with self._lock:
            old = self._entries.pop(key, None)
            self._bytes += array.nbytes - (0 if old is None else old.nbytes)
            self._entries[key] = array
            while self._bytes > self.max_bytes:
                self._bytes -= self._entries.popitem(last=False)[1].nbytes

    def clear(self) -> None:
        with self._lock:
            self._entries.clear()
            self._bytes = 0


TABLE_CACHE_BYTES = 64 * 2**20
"""Bound of the blurred-pattern tables kept for the next render (least recently used dropped first)."""
_TABLES = _KeptArrays(TABLE_CACHE_BYTES)


def _blurred_table(role: FrameRole, lo: float, step: float, n: int, sigma: float, gamma: float) -> FloatArray:
    """``n`` samples from ``lo`` by ``step`` of the blurred pattern ``G_sigma * pattern^gamma``: the
    stepped pattern's cell means of 8 sub-samples, blurred by a Gaussian truncated at 6 sigma
    (:func:`~metrology.core.simulate.options.blur_line`: by FFT for long kernels).

    Renders of one scene draw the same table again and again (a Monte Carlo over noise seeds), and
    the blur is most of a render's cost: tables are kept, bounded by :data:`TABLE_CACHE_BYTES`. A
    kept table is the one computed for the same arguments, so the images do not depend on the cache.
    """
    key = (role, lo, step, n, sigma, gamma)
    kept = _TABLES.get(key)
    if kept is not None:
        return kept
    from metrology.core.simulate.options import blur_line

    sub = (np.arange(8) + 0.5) / 8 - 0.5
    fine = (lo + np.arange(n)[:, None] * step + sub[None, :] * step).ravel()
    table = pattern_value(role, fine)
    if gamma != 1.0:
        table = table**gamma
    table = table.reshape(n, 8).mean(axis=1)
    table = blur_line(table, sigma / step, 6.0, "nearest")
    _TABLES.keep(key, table)
    return table


def square_wave_bias_px(steps: int, period: float, blur_px: float, harmonics: int = 200) -> float:
    """First-order bound on the coordinate error of an N-step phase of a blurred square wave, px.

    A 50 % square wave holds the odd harmonics m with amplitude ``1/m`` of the fundamental;
    a Gaussian blur of sigma scales harmonic m by ``exp(-2 pi^2 sigma^2 m^2 / P^2)``. The N-step
    least-squares phase sees harmonic m as the fundamental when ``m = k N +- 1``, so
    ``|d theta| <= sum_{odd m = k N +- 1} (1/m) exp(-2 pi^2 sigma^2 (m^2 - 1) / P^2)`` and
    ``|d x| <= P / (2 pi) |d theta|``.
    """
    total = 0.0
    m_values = sorted({k * steps + d for k in range(1, harmonics) for d in (-1, 1)})
    for m in m_values:
        if m > 1 and m % 2 == 1:
            total += math.exp(-2 * math.pi**2 * blur_px**2 * (m * m - 1) / period**2) / m
    return period / (2 * math.pi) * total


def codec_patterns(codec: Codec) -> npt.NDArray[np.uint8]:
    """The projector images of ``codec``: ``(frames, projector_height, projector_width)`` uint8.

    Each image is :func:`pattern_value` at the projector pixel centres (``x = column`` for
    u frames, ``x = row`` for v frames), scaled to 0..255 and rounded. A codec with
    ``precompensated_gamma = g`` writes ``round(255 s**(1/g))`` instead of ``round(255 s)``.
    """
    width, height = codec.projector_width, codec.projector_height
    images = np.zeros((codec.n_frames, height, width), np.uint8)
    columns = np.arange(width, dtype=np.float64)
    rows = np.arange(height, dtype=np.float64)
    for f, role in enumerate(frame_roles(codec)):
        if role.kind == "white":
            images[f] = 255
        elif role.kind in ("phase", "gray"):
            value = pattern_value(role, columns if role.axis == "u" else rows)
            if codec.precompensated_gamma is not None:
                value = value ** (1.0 / codec.precompensated_gamma)
            line = np.round(value * 255).astype(np.uint8)
            images[f] = line[None, :] if role.axis == "u" else line[:, None]
    return images


def default_projector_blur_px(options: SimulationOptions) -> float:
    """The projector blur of ``options`` in projector px: ``projector_defocus_codes * 8`` (:data:`PIXELS_PER_CODE`)."""
    return options.projector_defocus_codes * PIXELS_PER_CODE


def render_codec(
    codec: Codec,
    u: npt.ArrayLike | None,
    v: npt.ArrayLike | None = None,
    options: SimulationOptions | None = None,
    *,
    albedo: npt.ArrayLike = 1.0,
    projector_blur_px: float | None = None,
    seed: int | np.random.SeedSequence | None = None,
) -> np.ndarray:
    """Camera images of ``codec`` for a scene given by its true projector coordinates.

    Parameters
    ----------
    codec : Codec
    u, v : (H s, W s) float64 arrays or None
        True projector column (u) and row (v) coordinate of the surface point each camera
        (sub-)pixel sees, projector units (``x = j`` is the centre of column/row ``j``); NaN
        where the projector does not reach (shadow, background). Needed for each axis the
        codec codes (either may be None when the codec does not code it). With
        ``options.supersample = s > 1`` they are sampled on an ``s`` times finer grid (sub-pixel
        centres) and the images are area-averaged to ``(H, W)``; otherwise ``s = 1``.
        A pixel is lit where every coded axis's coordinate is finite and inside the
        projector, ``[-0.5, size - 0.5]``.
    options : SimulationOptions, optional
        Bit depth, noise (grey levels), ambient, projector gain, projector gamma, camera
        defocus (px), supersample and seed; default noise-free 16-bit.
    albedo : float or (H s, W s) array
        Surface reflectance, default 1.
    projector_blur_px : float, optional
        Gaussian sigma of the projector blur along the coded axis, projector units; default
        ``8 * options.projector_defocus_codes`` (1.2 px for the realistic preset).
    seed : int or SeedSequence, optional
        Noise seed; default ``options.seed``.

    Returns
    -------
    images : (frames, H, W) uint8 or uint16 array
        ``round(full_scale * albedo * (ambient + gain * E_f)) + noise``, clipped to
        ``[0, full_scale]``.

    Raises
    ------
    ValueError
        If a coded axis has no coordinates or the shapes disagree.
    """
    from metrology.core.simulate.options import SimulationOptions, camera_image

    opts = options if options is not None else SimulationOptions()
    coords: dict[str, FloatArray] = {}
    shape: tuple[int, ...] | None = None
    for name, value in (("u", u), ("v", v)):
        if value is None:
            if name in codec.axes:
                raise ValueError(f"the codec codes axis {name}: give its true coordinates")
            continue
        array = np.asarray(value, dtype=np.float64)
        if array.ndim != 2:
            raise ValueError(f"{name} must be an (H, W) array, got shape {array.shape}")
        if shape is not None and array.shape != shape:
            raise ValueError(f"u and v must have one shape, got {shape} and {array.shape}")
        shape = array.shape
        coords[name] = array
    if shape is None:
        raise ValueError("give u and/or v")
    s = opts.supersample
    if shape[0] % s or shape[1] % s:
        raise ValueError(f"with supersample {s}, u and v must have a shape divisible by {s}, got {shape}")
    height, width = shape[0] // s, shape[1] // s
    lit = np.ones(shape, bool)
    for name in codec.axes:
        x = coords[name]
        with np.errstate(invalid="ignore"):
            lit &= np.isfinite(x) & (x >= -0.5) & (x <= codec.extent(name) - 0.5)
    albedo_map = np.broadcast_to(np.asarray(albedo, dtype=np.float64), shape)
    blur = default_projector_blur_px(opts) if projector_blur_px is None else float(projector_blur_px)
    if not math.isfinite(blur) or blur < 0:
        raise ValueError(f"projector_blur_px must be finite and >= 0, got {projector_blur_px!r}")
    full = float(opts.full_scale)
    rng = np.random.default_rng(opts.seed if seed is None else seed)
    # the projected value of a pre-compensated codec is s**(1/g); the projector emits it**gamma
    gamma = opts.projector_gamma / (codec.precompensated_gamma or 1.0)

    def clean_frames() -> Iterator[FloatArray]:
        from metrology.core.simulate.kernels import lit_intensity, sine_intensity

        lit_index = np.flatnonzero(lit)
        lit_coords = {name: x.ravel()[lit_index] for name, x in coords.items()}
        base = (albedo_map * opts.ambient).ravel()
        gain = (albedo_map * opts.projector_gain).ravel()[lit_index]
        # cos and sin of a sequence's step-0 phase a, once: step k's cos(a + p_k) = cos a cos p_k - sin a sin p_k
        angles: dict[tuple[str, float, float], tuple[FloatArray, FloatArray]] = {}
        intensity = np.empty(shape)
        flat = intensity.reshape(-1)
        for role in frame_roles(codec):
            seq = role.sequence
            if role.kind == "phase" and seq is not None and seq.waveform == "sine" and gamma == 1.0:
                key = (role.axis, seq.origin, seq.period)
                if key not in angles:
                    angle = _sine_angle(seq, lit_coords[role.axis])
                    angles[key] = (np.cos(angle), np.sin(angle, out=angle))
                cos_a, sin_a = angles[key]
                shift = 2 * np.pi * seq.shift * role.step / seq.steps
                amplitude = 0.5 * (_sine_damping(seq, blur) if blur > 0 else 1.0)
                sine_intensity(
                    base,
                    lit_index,
                    gain,
                    cos_a,
                    sin_a,
                    0.5,
                    amplitude * math.cos(shift),
                    amplitude * math.sin(shift),
                    flat,
                )
            else:
                if role.kind in ("phase", "gray"):
                    emitted = _emitted(role, lit_coords[role.axis], blur, gamma)
                else:
                    emitted = _emitted(role, np.zeros(lit_index.size), 0.0, gamma)
                lit_intensity(base, lit_index, gain, emitted, flat)  # base, + gain E where lit
            yield camera_image(intensity, height, width, opts) * full

    frames: Iterable[FloatArray] = clean_frames()
    clean_bytes = codec.n_frames * height * width * 8
    # noise drawn anew on a kept noise-free render (a Monte Carlo's renders); a render too large to
    # keep is never looked up (its scene's digest, a hash of every coordinate, would be wasted)
    if opts.noise_grey > 0 and _CLEAN.fits(clean_bytes):
        key = (repr(codec), _digest(coords, albedo), dataclasses.replace(opts, seed=0), blur)
        frames = _kept_clean_render(key, frames, clean_bytes)
    images = np.empty((codec.n_frames, height, width), opts.dtype)
    for f, grey in enumerate(frames):
        if opts.noise_grey > 0:  # grey + noise_grey * z, in place on the draw z
            noisy = rng.standard_normal(grey.shape)
            noisy *= opts.noise_grey
            noisy += grey
            np.rint(noisy, out=noisy)
        else:
            noisy = np.rint(grey)
        images[f] = np.clip(noisy, 0, full, out=noisy)
    return images


CLEAN_CACHE_BYTES = 128 * 2**20
"""Bound of the noise-free renders kept (least recently used dropped first): a noisy render of the
same coordinates, reflectance and options but another seed then only draws its noise."""
_CLEAN = _KeptArrays(CLEAN_CACHE_BYTES)


def _digest(coords: dict[str, FloatArray], albedo: npt.ArrayLike) -> str:
    """SHA-1 of the true coordinates and the reflectance (a scalar or a map as given, not broadcast):
    a render's whole scene."""
    h = hashlib.sha1()
    for name in sorted(coords):
        h.update(name.encode())
        h.update(np.ascontiguousarray(coords[name]).data)
    reflectance = np.ascontiguousarray(albedo, dtype=np.float64)
    h.update(repr(reflectance.shape).encode())
    h.update(reflectance.data)
    return h.hexdigest()


def _kept_clean_render(key: tuple[object, ...], frames: Iterable[FloatArray], nbytes: int) -> Iterable[FloatArray]:
    """The noise-free frames ``(frames, H, W)`` float64 grey levels of ``key``: kept ones, or
    ``frames`` computed now and kept when they fit a quarter of :data:`CLEAN_CACHE_BYTES`."""
    kept = _CLEAN.get(key)
    if kept is not None:
        return kept
    if not _CLEAN.fits(nbytes):
        return frames
    stack = np.stack(list(frames))
    _CLEAN.keep(key, stack)
    return stack
