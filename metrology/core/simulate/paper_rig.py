"""The paper's crossed-axes virtual rig: the exact forward model of Figs. 1 and 3, rendering the
eleven gcps-v1 camera images of a scene (docs/conventions.md) and its true light codes.

The forward model is the exact crossed-optical-axes geometry of the paper (Figs. 1 and 3):

1. **Camera rays.** Pixel (k, j) looks from C = (d, 0, L) at A = (x_A[j], Y_A[k], 0) on R; the
   point of the ray at height z is ``X = d + (1 - z/L)(x_A - d)``, ``Y = (1 - z/L) Y_A``.
   The first hit of the scene's height field along the ray is found by marching down from
   ``z_max`` in steps that move the ray at most :data:`MARCH_STEP_MM` sideways, then bracketing
   the crossing to :data:`HIT_TOLERANCE_MM` (Illinois false position with bisection
   safeguards). Smooth scenes whose slope bound proves a single crossing skip the march.
   Flat surfaces (planes, block top, treads) come out exact.
2. **Projector shadows.** A hit H is lit only if the segment H -> P = (0, 0, L) stays above
   the height field up to ``z_max`` (same sideways step), which also gives attached shadows.
3. **Light code.** The light plane through H lands on R at ``x_B = X L / (L - z)``; its code is
   the inverse of Eq. 14 (:func:`~metrology.core.geometry.crossed_axes.codes_from_abscissa`). Outside
   [0, nlp] the projector emits no light.
4. **Radiometry.** ``I = albedo * (ambient + gain * E(l))`` in fractions of full scale, where
   ``E = G_sigma * (pattern(l)^gamma * [0 <= l <= nlp])`` is the light the projector emits
   (its gamma acts on the pattern value; its defocus is a Gaussian of ``sigma`` codes across
   the fringes). Shadowed points get ``albedo * ambient``.
5. **Camera.** Each pixel averages ``supersample x supersample`` sub-rays over its area
   (``camera_sampling="area"``: mixed pixels at discontinuities and shadow edges), or takes the
   light of the one ray through its centre (``camera_sampling="centre"``: a point sample, whose
   only mixing is the blur that follows); then a Gaussian camera blur, seeded Gaussian noise in
   grey levels, rounding and clipping to 8 or 16 bits.

Square-wave projection (``square=True``) with ``smoothing_codes > 0`` models the paper's
square fringes made near-sinusoidal: the smoothing is a Gaussian of ``smoothing_codes`` code
units applied to the phase patterns only, on the projector side (in code space, so it does not
blur across the object's depth discontinuities). The decoder may additionally smooth the
acquired images; that is decoding's business, not the rig's.

The module does no file I/O: writing a capture stack is :mod:`metrology.core.io`'s job.

Examples
--------
>>> from metrology.core.geometry.crossed_axes import PAPER_RIG
>>> from metrology.core.scenes import make_scene
>>> stack = render_stack(PAPER_RIG, make_scene("plane", z_mm=20.0))
>>> stack.images.shape, stack.images.dtype.name, float(np.nanmax(np.abs(stack.truth_mm - 20.0)))
((11, 480, 640), 'uint16', 0.0)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core.geometry.crossed_axes import Rig, camera_ray_point, codes_of_points
from metrology.core.patterns import GRAY_NAMES, PATTERN_NAMES, PHASE_NAMES, pattern_intensity
from metrology.core.scenes import Scene, StageScene
from metrology.core.simulate.options import SimulationOptions, _is_int, blur_line, camera_image
from metrology.core.simulate.series import series_seed, stack_seed

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

MARCH_STEP_MM = 0.5
"""Largest sideways move of a camera or shadow ray between two samples of the height field, mm."""

HIT_TOLERANCE_MM = 1e-9
"""Width of the bracket on the first hit's height when the root search stops, mm."""

SHADOW_EPS_MM = 1e-6
"""A hit is shadowed only where the height field rises more than this above the segment to P."""

EDGE_JUMP_MM = 2.0
"""Height jump between neighbouring pixels (or within a pixel) marking a depth discontinuity, mm."""

CODE_GRID_STEP = 1.0 / 256.0
"""Sampling of the projector patterns in code space when they are blurred, code units."""


# --------------------------------------------------------------------------- results
@dataclass(frozen=True, eq=False)
class RenderedStack:
    """One simulated capture and its ground truth.

    Attributes
    ----------
    images : (11, H, W) uint8 or uint16 array
        Camera images in :data:`~metrology.core.patterns.PATTERN_NAMES` order.
    truth_mm : (H, W) float32 array
        Height above R of the first surface hit along the ray through each pixel centre, mm;
        NaN where not measurable (projector shadow, code outside [0, nlp]).
    codes : (H, W) float64 array
        True light code at the hit point of each pixel centre, code units; NaN where not lit.
    lit : (H, W) bool array
        Pixel centre's hit point is illuminated by the coded field (not in shadow and
        0 <= code <= nlp); equals ``isfinite(truth_mm)``.
    edges : (H, W) bool array
        Pixels at a depth discontinuity (a height jump of more than :data:`EDGE_JUMP_MM` to a
        4-neighbour or within the pixel) or at a lit/unlit boundary (shadow or field edge).
        Dilate it for the band where mixed pixels are expected.
    hit_mm : (H, W) float64 array
        Height of the first hit at each pixel centre, lit or not, mm.
    scene : Scene
        The rendered scene (its analytic parameters).
    options : SimulationOptions
        The options used (provenance; the noise seed is derived from ``options.seed`` and the
        scene in :func:`render_stack` (:func:`stack_seed`), and from ``options.seed``, the
        position and the repeat in :func:`render_series` (:func:`series_seed`)).
    """

    images: npt.NDArray[np.unsignedinteger[Any]]
    truth_mm: npt.NDArray[np.float32]
    codes: FloatArray
    lit: BoolArray
    edges: BoolArray
    hit_mm: FloatArray
    scene: Scene
    options: SimulationOptions

    def image(self, name: str) -> npt.NDArray[np.unsignedinteger[Any]]:
        """The image of pattern ``name`` (e.g. ``"PS_0"``): (H, W) view of :attr:`images`."""
        if name not in PATTERN_NAMES:
            raise ValueError(f"unknown pattern name {name!r}; expected one of {', '.join(PATTERN_NAMES)}")
        return self.images[PATTERN_NAMES.index(name)]


@dataclass(frozen=True, eq=False)
class _CleanRender:
    """Noise-free, unquantised images (grey levels) and truth: shared by repeats."""

    grey: FloatArray  # (11, H, W) float64, grey levels of the output depth
    truth_mm: npt.NDArray[np.float32]
    codes: FloatArray
    lit: BoolArray
    edges: BoolArray
    hit_mm: FloatArray
    scene: Scene
    options: SimulationOptions


@dataclass(frozen=True)
class _Trace:
    """Geometry of a set of rays (flat arrays)."""

    z: FloatArray  # first-hit height, mm
    X: FloatArray  # hit point X, mm
    Y: FloatArray  # hit point Y, mm
    codes: FloatArray  # light code of the plane through the hit point
    illuminated: BoolArray  # not in projector shadow
    in_field: BoolArray  # 0 <= code <= nlp


# --------------------------------------------------------------------------- public API
def render_stack(rig: Rig, scene: Scene, options: SimulationOptions | None = None) -> RenderedStack:
    """Render the eleven camera images of ``scene`` seen through ``rig``.

    Parameters
    ----------
    rig : Rig
        The rig geometry (image size, L, d, alpha, FW, nlp).
    scene : Scene
        The surface (see :mod:`metrology.core.scenes`); it must stay below the pupils.
    options : SimulationOptions, optional
        Default ``SimulationOptions()`` (noise-free, 16-bit, exact).

    Returns
    -------
    RenderedStack
        Images ``(11, H, W)`` uint8/uint16 plus ``truth_mm``, ``codes``, ``lit``, ``edges``.

    Raises
    ------
    TypeError
        If an argument has the wrong type.
    ValueError
        If the scene reaches the pupils' height.
    """
    opts = _check_inputs(rig, scene, options)
    clean = _render_clean(rig, scene, opts)
    return _capture(clean, np.random.default_rng(stack_seed(opts, scene)))


def render_flat_frames(
    rig: Rig, scene: Scene, options: SimulationOptions | None = None
) -> tuple[FloatArray, FloatArray]:
    """The noise-free camera images of ``scene`` under a white and under a black projector frame.

    The same light path as :func:`render_stack` (rays, shadows, albedo, pixel sampling, camera
    blur) with a uniform emitted value: ``I = albedo (ambient + gain * illuminated * e)``, e = 1
    (white) or 0 (black), times the full scale. The coded field's limits do not apply (a flat
    frame lights the whole projector field).

    Returns
    -------
    white, black : (H, W) float64 arrays
        Grey levels of the output depth, unquantised and unclipped (the caller adds noise).
    """
    opts = _check_inputs(rig, scene, options)
    H, W = rig.shape
    s = 1 if opts.camera_sampling == "centre" else opts.supersample
    pitch = rig.fw_mm / (W * s)
    xa = rig.d_mm - rig.fw_mm / 2 + (np.arange(W * s) + 0.5) * pitch
    ya = (np.arange(H * s) + 0.5 - H * s / 2) * pitch
    XA, YA = np.meshgrid(xa, ya)
    rays = _trace(rig, scene, XA.ravel(), YA.ravel())
    albedo = scene.albedo(rays.X, rays.Y).reshape(H * s, W * s)
    illuminated = rays.illuminated.reshape(H * s, W * s)
    full = float(opts.full_scale)
    frames = []
    for emitted in (1.0, 0.0):
        intensity = albedo * opts.ambient + albedo * opts.projector_gain * illuminated * emitted
        img = camera_image(intensity, H, W, opts)
        frames.append(np.asarray(img, dtype=np.float64) * full)
    return frames[0], frames[1]


def paper_series(
    rig: Rig,
    z_in_mm: Sequence[float],
    repeats: int,
    options: SimulationOptions | None = None,
    scene_factory: Callable[[float], Scene] | None = None,
) -> Iterator[tuple[float, int, RenderedStack]]:
    """Render a stage series (paper section 5): ``repeats`` captures at each ``Z_in``.

    The noise-free geometry and radiometry are rendered once per position; each repeat only
    draws fresh camera noise, seeded by :func:`series_seed` (and the scene, as :func:`render_stack`)
    so any capture can be reproduced alone.

    Parameters
    ----------
    rig : Rig
    z_in_mm : sequence of float
        Stage positions Z_in, mm.
    repeats : int
        Captures per position, >= 1.
    options : SimulationOptions, optional
    scene_factory : callable, optional
        ``Z_in -> Scene``; default a :class:`~metrology.core.scenes.StageScene` plane at Z_in.

    Yields
    ------
    (z_in_mm, repeat, RenderedStack)
        In position order, repeats innermost.

    Raises
    ------
    ValueError
        If ``repeats`` < 1 or a position is not finite (checked before rendering).
    """
    opts = _check_inputs(rig, None, options)
    if not _is_int(repeats) or repeats < 1:
        raise ValueError(f"repeats must be a positive integer, got {repeats!r}")
    positions = [float(z) for z in z_in_mm]
    for z in positions:
        if not math.isfinite(z):
            raise ValueError(f"z_in_mm must be finite, got {z!r}")
    factory: Callable[[float], Scene] = scene_factory or (lambda z: StageScene(z_in_mm=z))
    return _series(rig, positions, int(repeats), opts, factory)


def _series(
    rig: Rig,
    positions: list[float],
    repeats: int,
    opts: SimulationOptions,
    factory: Callable[[float], Scene],
) -> Iterator[tuple[float, int, RenderedStack]]:
    for index, z in enumerate(positions):
        scene = factory(z)
        _check_inputs(rig, scene, opts)
        clean = _render_clean(rig, scene, opts)
        for repeat in range(repeats):
            capture_opts = replace(opts, seed=series_seed(opts.seed, index, repeat))
            yield z, repeat, _capture(clean, np.random.default_rng(stack_seed(capture_opts, scene)))


def emitted_pattern(codes: npt.ArrayLike, name: str, nlp: int, options: SimulationOptions) -> FloatArray:
    """Light the projector sends along the plane of code ``l``, relative to white.

    ``E(l) = G_sigma * (pattern(l)^gamma * [0 <= l <= nlp])`` with ``sigma`` the projector
    defocus (and, for phase patterns, the smoothing combined in quadrature).

    Parameters
    ----------
    codes : array_like of float, any shape
        Light codes, code units.
    name : str
        Pattern name (:data:`~metrology.core.patterns.PATTERN_NAMES`).
    nlp : int
        Codes in the field.
    options : SimulationOptions

    Returns
    -------
    emitted : float64 ndarray, same shape as ``codes``, in [0, 1]
    """
    l = np.asarray(codes, dtype=np.float64)
    sigma = _pattern_sigma(name, options)
    if sigma == 0.0:
        return _exact_emitted(l, name, nlp, options)
    pad = _table_pad(sigma)
    return _CodeSampler(l, pad).sample(_blurred_table(name, nlp, sigma, options.square, options.projector_gamma, pad))


def _pattern_sigma(name: str, options: SimulationOptions) -> float:
    """Total Gaussian blur of pattern ``name`` in code units (defocus, plus smoothing for PS)."""
    if name in PHASE_NAMES:
        return math.hypot(options.projector_defocus_codes, options.smoothing_codes)
    if name in GRAY_NAMES:
        return options.projector_defocus_codes
    raise ValueError(f"unknown pattern name {name!r}; expected one of {', '.join(PATTERN_NAMES)}")


def _exact_emitted(l: FloatArray, name: str, nlp: int, options: SimulationOptions) -> FloatArray:
    inside = (l >= 0.0) & (l <= nlp)
    value = np.where(inside, pattern_intensity(np.where(inside, l, 0.0), name, options.square), 0.0)
    return value if options.projector_gamma == 1.0 else value**options.projector_gamma


def _table_pad(sigma: float) -> float:
    """Grid margin beyond the field: at least 8 sigma + 2 codes, a whole number of codes."""
    return float(math.ceil(8.0 * sigma + 2.0))


class _CodeSampler:
    """Linear interpolation of tables on the uniform code grid ``-pad + n * CODE_GRID_STEP``.

    The cell index and fraction of each code are computed once and reused for every pattern.
    """

    def __init__(self, codes: FloatArray, pad: float) -> None:
        t = (codes + pad) * (1.0 / CODE_GRID_STEP)
        t[~np.isfinite(t)] = 0.0
        np.maximum(t, 0.0, out=t)
        self.pad = pad
        self.index = t.astype(np.intp)
        self.frac = t - self.index
        self._size = -1  # the table size the clamped cells below are for

    def _cells(self, table: FloatArray) -> None:
        last = table.size - 1
        if table.size != self._size:  # the clamped cells of every table of this size, once
            self._below = np.minimum(self.index, last - 1)
            self._above = self._below + 1
            self._frac = np.where(self.index >= last, 0.0, self.frac)
            self._size = table.size

    def light(self, table: FloatArray, signal: FloatArray, ambient: FloatArray) -> FloatArray:
        """``ambient + signal * sample(table)`` (arrays of the codes' shape), in one compiled pass."""
        from metrology.core.simulate.kernels import sample_light

        self._cells(table)
        out = np.empty(self.index.shape)
        signal = np.ascontiguousarray(signal, dtype=np.float64)
        ambient = np.ascontiguousarray(ambient, dtype=np.float64)
        below = np.ascontiguousarray(self._below).reshape(-1)
        frac = np.ascontiguousarray(self._frac).reshape(-1)
        sample_light(table, below, frac, signal.reshape(-1), ambient.reshape(-1), out.reshape(-1))
        return out

    def sample(self, table: FloatArray) -> FloatArray:
        """Values of ``table`` (zero at both ends, extended by zeros) at the codes."""
        self._cells(table)
        base = table.take(self._below)
        step = table.take(self._above)
        step -= base
        step *= self._frac
        step += base
        return step


# --------------------------------------------------------------------------- rendering
def _check_inputs(rig: Any, scene: Any, options: Any) -> SimulationOptions:
    if not isinstance(rig, Rig):
        raise TypeError(f"rig must be a Rig, got {type(rig).__name__}")
    if scene is not None:
        if not isinstance(scene, Scene):
            raise TypeError(f"scene must be a Scene, got {type(scene).__name__}")
        if scene.z_max_mm >= rig.L_mm * 0.95:
            raise ValueError(f"scene reaches {scene.z_max_mm:g} mm, too close to the pupils at L = {rig.L_mm:g} mm")
    if options is None:
        return SimulationOptions()
    if not isinstance(options, SimulationOptions):
        raise TypeError(f"options must be SimulationOptions, got {type(options).__name__}")
    return options


def _render_clean(rig: Rig, scene: Scene, opts: SimulationOptions) -> _CleanRender:
    H, W = rig.shape
    s = opts.supersample
    pitch = rig.fw_mm / (W * s)
    xa = rig.d_mm - rig.fw_mm / 2 + (np.arange(W * s) + 0.5) * pitch
    ya = (np.arange(H * s) + 0.5 - H * s / 2) * pitch
    XA, YA = np.meshgrid(xa, ya)
    sub = _trace(rig, scene, XA.ravel(), YA.ravel())

    centre_rays = _centre_rays(rig, scene, sub, H, W, s)
    z_c, codes_c = centre_rays.z.reshape(H, W), centre_rays.codes.reshape(H, W)
    lit_c = (centre_rays.illuminated & centre_rays.in_field).reshape(H, W)

    truth = np.where(lit_c, z_c, np.nan).astype(np.float32)
    codes = np.where(lit_c, codes_c, np.nan)
    edges = _edge_mask(z_c, lit_c)
    if s > 1:
        z4 = sub.z.reshape(H, s, W, s)
        lit4 = (sub.illuminated & sub.in_field).reshape(H, s, W, s)
        edges |= (z4.max(axis=(1, 3)) - z4.min(axis=(1, 3))) > EDGE_JUMP_MM
        edges |= lit4.any(axis=(1, 3)) != lit4.all(axis=(1, 3))

    # the rays whose light the pixels gather: all sub-rays (area) or the centre rays (centre)
    rays, rows, cols = (centre_rays, H, W) if opts.camera_sampling == "centre" else (sub, H * s, W * s)
    albedo = scene.albedo(rays.X, rays.Y).reshape(rows, cols)
    illuminated = rays.illuminated.reshape(rows, cols)
    sub_codes = rays.codes.reshape(rows, cols)
    signal = albedo * opts.projector_gain * illuminated
    ambient = albedo * opts.ambient
    grey = np.empty((len(PATTERN_NAMES), H, W), dtype=np.float64)
    full = float(opts.full_scale)
    sigmas = [_pattern_sigma(name, opts) for name in PATTERN_NAMES]
    pad = _table_pad(max(sigmas))
    sampler = _CodeSampler(sub_codes, pad) if max(sigmas) > 0 else None
    for p, name in enumerate(PATTERN_NAMES):
        if sampler is None or sigmas[p] == 0.0:
            intensity = ambient + signal * _exact_emitted(sub_codes, name, rig.nlp, opts)
        else:  # ambient + signal * E, E the blurred table at the codes
            table = _blurred_table(name, rig.nlp, sigmas[p], opts.square, opts.projector_gamma, pad)
            intensity = sampler.light(table, signal, ambient)
        img = camera_image(intensity, H, W, opts)
        grey[p] = img * full
    return _CleanRender(grey, truth, codes, lit_c, edges, z_c, scene, opts)


def _centre_rays(rig: Rig, scene: Scene, sub: _Trace, H: int, W: int, s: int) -> _Trace:
    """The rays through the pixel centres (flat, H * W): the middle sub-ray of each pixel when
    ``s`` is odd, else traced anew."""
    if s % 2 == 0:
        XC, YC = np.meshgrid(rig.column_x_mm(), rig.row_y_mm())
        return _trace(rig, scene, XC.ravel(), YC.ravel())
    c = s // 2

    def centre(a: npt.NDArray[Any]) -> npt.NDArray[Any]:
        return np.ascontiguousarray(a.reshape(H, s, W, s)[:, c, :, c]).ravel()

    return _Trace(
        z=centre(sub.z),
        X=centre(sub.X),
        Y=centre(sub.Y),
        codes=centre(sub.codes),
        illuminated=centre(sub.illuminated),
        in_field=centre(sub.in_field),
    )


def _capture(clean: _CleanRender, rng: np.random.Generator) -> RenderedStack:
    opts = clean.options
    if opts.noise_grey > 0:  # grey + noise_grey * z (z float32, scaled in float32), rounded in place
        noise = rng.standard_normal(clean.grey.shape, dtype=np.float32)
        noise *= opts.noise_grey
        values = clean.grey + noise
        np.rint(values, out=values)
    else:
        values = np.rint(clean.grey)
    images = np.clip(values, 0, opts.full_scale, out=values).astype(opts.dtype)
    return RenderedStack(
        images=images,
        truth_mm=clean.truth_mm,
        codes=clean.codes,
        lit=clean.lit,
        edges=clean.edges,
        hit_mm=clean.hit_mm,
        scene=clean.scene,
        options=opts,
    )


def _edge_mask(z: FloatArray, lit: BoolArray) -> BoolArray:
    edges = np.zeros(z.shape, dtype=bool)
    jump_x = (np.abs(np.diff(z, axis=1)) > EDGE_JUMP_MM) | (lit[:, 1:] != lit[:, :-1])
    jump_y = (np.abs(np.diff(z, axis=0)) > EDGE_JUMP_MM) | (lit[1:, :] != lit[:-1, :])
    edges[:, 1:] |= jump_x
    edges[:, :-1] |= jump_x
    edges[1:, :] |= jump_y
    edges[:-1, :] |= jump_y
    return edges


_TABLE_CACHE: dict[tuple[str, int, float, bool, float, float], FloatArray] = {}


def _blurred_table(name: str, nlp: int, sigma: float, square: bool, gamma: float, pad: float) -> FloatArray:
    """Emitted pattern blurred by ``sigma`` codes, on the grid ``-pad + n * CODE_GRID_STEP``.

    The grid covers ``[-pad, nlp + pad]``; with ``pad >= 8 sigma + 2`` the table is zero at both
    ends. Tables are cached (a stage series reuses them at every position).
    """
    key = (name, nlp, sigma, square, gamma, pad)
    cached = _TABLE_CACHE.get(key)
    if cached is not None:
        return cached
    n = round((nlp + 2 * pad) / CODE_GRID_STEP) + 1
    # Each grid value is the mean over its cell (8 sub-samples): the pattern's steps, at integer
    # codes (on grid points), then fall half-way and the blurred table has no half-cell bias.
    sub = (np.arange(8) + 0.5) / 8 - 0.5
    fine = (-pad + np.arange(n)[:, None] * CODE_GRID_STEP + sub[None, :] * CODE_GRID_STEP).ravel()
    inside = (fine >= 0.0) & (fine <= nlp)
    emitted = np.where(inside, pattern_intensity(np.where(inside, fine, 0.0), name, square), 0.0)
    if gamma != 1.0:
        emitted = emitted**gamma
    emitted = emitted.reshape(n, 8).mean(axis=1)
    table = blur_line(emitted, sigma / CODE_GRID_STEP, 8.0, "constant")
    table[0] = table[-1] = 0.0
    if len(_TABLE_CACHE) > 64:
        _TABLE_CACHE.clear()
    _TABLE_CACHE[key] = table
    return table


# --------------------------------------------------------------------------- ray casting
def _trace(rig: Rig, scene: Scene, xa: FloatArray, ya: FloatArray) -> _Trace:
    """First hits, shadows and codes of the camera rays through (xa, ya) on R (flat arrays)."""
    z = _first_hit(rig, scene, xa, ya)
    X, Y = (np.asarray(a, dtype=np.float64) for a in camera_ray_point(rig, xa, ya, z))
    illuminated = ~_shadowed(rig, scene, X, Y, z)
    codes = np.asarray(codes_of_points(rig, X, z), dtype=np.float64)
    in_field = illuminated & (codes >= 0.0) & (codes <= rig.nlp)
    return _Trace(z=z, X=X, Y=Y, codes=codes, illuminated=illuminated, in_field=in_field)


def _slab(px: FloatArray, py: FloatArray, box: tuple[float, float, float, float]) -> tuple[FloatArray, FloatArray]:
    """Interval of s where ``s * (px, py)`` lies in ``box`` (empty when lower > upper): per axis
    ``[a / p, b / p]`` sorted, or every s (the slab holds 0) or none where ``p == 0``
    (:func:`~metrology.core.simulate.kernels.slab_interval`)."""
    from metrology.core.simulate.kernels import slab_interval

    px = np.ascontiguousarray(px, dtype=np.float64)
    py = np.ascontiguousarray(py, dtype=np.float64)
    lo, hi = np.empty(px.shape), np.empty(px.shape)
    x0, x1, y0, y1 = (float(b) for b in box)
    slab_interval(px.reshape(-1), py.reshape(-1), x0, x1, y0, y1, lo.reshape(-1), hi.reshape(-1))
    return lo, hi


def _boxes_interval(
    px: FloatArray, py: FloatArray, ox: float, boxes: tuple[tuple[float, float, float, float], ...], s_min: float
) -> tuple[FloatArray, FloatArray]:
    """Hull of the s-intervals in [s_min, 1] where ``(ox + s px, s py)`` lies in one of ``boxes``."""
    lo = np.full(px.shape, np.inf)
    hi = np.full(px.shape, -np.inf)
    for x0, x1, y0, y1 in boxes:
        a, b = _slab(px, py, (x0 - ox, x1 - ox, y0, y1))
        np.maximum(a, s_min, out=a)
        np.minimum(b, 1.0, out=b)
        ok = a <= b
        lo = np.where(ok, np.minimum(lo, a), lo)
        hi = np.where(ok, np.maximum(hi, b), hi)
    return lo, hi


def _first_hit(rig: Rig, scene: Scene, xa: FloatArray, ya: FloatArray) -> FloatArray:
    """Height of the highest crossing of each camera ray with the height field, mm.

    The ray through A = (xa, ya, 0) is ``X = d + k (xa - d)``, ``Y = k ya`` at height
    ``z = L (1 - k)``. Only the part of the ray over the scene's footprint boxes is searched;
    elsewhere the height field is 0.
    """
    L, d = rig.L_mm, rig.d_mm
    z_max, z_min = scene.z_max_mm, scene.z_min_mm
    z = np.full(xa.shape, z_min)
    if z_max <= z_min:
        return z
    boxes = scene.footprints_mm
    if boxes:
        k_lo, k_hi = _boxes_interval(xa - d, ya, d, boxes, 1.0 - z_max / L)
        cand = np.flatnonzero(k_lo <= k_hi)
        top = np.minimum(L * (1.0 - k_lo[cand]), z_max)
        bottom = np.maximum(L * (1.0 - k_hi[cand]), z_min)
    else:
        cand = np.arange(xa.size)
        top = np.full(cand.size, z_max)
        bottom = np.full(cand.size, z_min)
    if cand.size == 0:
        return z
    xc, yc = xa[cand], ya[cand]

    def f(zv: FloatArray, idx: npt.NDArray[np.intp]) -> FloatArray:
        kk = 1.0 - zv / L
        return zv - scene.height_mm(d + kk * (xc[idx] - d), kk * yc[idx])

    rho = np.hypot(xc - d, yc) / L
    span = z_max - z_min
    dz = np.minimum(MARCH_STEP_MM / np.maximum(rho, MARCH_STEP_MM / span), span)
    # Start one step above the entry into the footprint (outside it f = z > 0), or at z_max.
    start = np.minimum(top + dz, z_max)
    every = np.arange(cand.size)
    f_start = f(start, every)
    result = np.full(cand.size, z_min)
    at_start = f_start <= 0.0  # only possible at z_max: the top of the field is touched
    result[at_start] = start[at_start]
    todo = np.flatnonzero(~at_start)
    if scene.smooth and scene.max_slope * float(rho.max(initial=0.0)) < 1.0:
        # f is strictly increasing along the ray: one crossing in [z_min, start].
        lo = np.full(todo.size, z_min)
        result[todo] = _refine(f, todo, lo, f(lo, todo), start[todo], f_start[todo], bisect_every=0)
    else:
        lo_b, hi_b, flo_b, fhi_b, idx_b = _march(f, todo, start[todo], bottom[todo], dz[todo], f_start[todo], z_min)
        result[idx_b] = _refine(f, idx_b, lo_b, flo_b, hi_b, fhi_b)
    z[cand] = result
    return z


def _march(
    f: Callable[[FloatArray, npt.NDArray[np.intp]], FloatArray],
    idx: npt.NDArray[np.intp],
    start: FloatArray,
    bottom: FloatArray,
    dz: FloatArray,
    f_start: FloatArray,
    z_min: float,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, npt.NDArray[np.intp]]:
    """March rays down from ``start`` until f <= 0 or ``bottom`` (below it the field is z_min).

    Returns the brackets (lo, hi, f(lo), f(hi)) and ray indices of the rays that crossed;
    the others keep the caller's default, the plane at ``z_min``.
    """
    z_cur = start.copy()
    f_cur = f_start.copy()
    active = np.arange(idx.size)
    out_lo, out_hi, out_flo, out_fhi, out_idx = [], [], [], [], []
    while active.size:
        z_next = np.maximum(z_cur[active] - dz[active], bottom[active])
        f_next = f(z_next, idx[active])
        hit = f_next <= 0.0
        # A wall falling away under the ray between two samples: did the ray clip its top edge?
        # (only where the ray passes closer to the surface than the drop: necessary for a clip)
        drop = (z_cur[active] - f_cur[active]) - (z_next - f_next)
        falling = np.flatnonzero(~hit & (drop > MARCH_STEP_MM) & (np.minimum(f_cur[active], f_next) < drop))
        if falling.size:
            rows = active[falling]
            edge_z, edge_f = _clipped_edge(
                f, idx[rows], z_next[falling], z_cur[rows], z_cur[rows] - f_cur[rows], z_next[falling] - f_next[falling]
            )
            clipped = edge_f <= 0.0
            # Bracket the crossing of the top face between the edge and the previous sample.
            z_next[falling[clipped]] = edge_z[clipped]
            f_next[falling[clipped]] = edge_f[clipped]
            hit[falling[clipped]] = True
        sel = active[hit]
        out_lo.append(z_next[hit])
        out_flo.append(f_next[hit])
        out_hi.append(z_cur[sel])
        out_fhi.append(f_cur[sel])
        out_idx.append(idx[sel])
        miss = ~hit
        left = active[miss]
        z_cur[left] = z_next[miss]
        f_cur[left] = f_next[miss]
        active = left[z_next[miss] > bottom[left]]
    if not out_idx:
        empty = np.empty(0)
        return empty, empty, empty, empty, np.empty(0, dtype=np.intp)
    cat = np.concatenate
    return cat(out_lo), cat(out_hi), cat(out_flo), cat(out_fhi), cat(out_idx)


def _refine(
    f: Callable[[FloatArray, npt.NDArray[np.intp]], FloatArray],
    idx: npt.NDArray[np.intp],
    lo: FloatArray,
    flo: FloatArray,
    hi: FloatArray,
    fhi: FloatArray,
    bisect_every: int = 4,
) -> FloatArray:
    """A root of f in each bracket ``f(lo) <= 0 < f(hi)``.

    Illinois false position, with a bisection step every ``bisect_every`` iterations (0: never;
    the safeguard for walls, where f jumps). A ray stops when ``|f| <= HIT_TOLERANCE_MM`` at the
    new point or the bracket is narrower than :data:`HIT_TOLERANCE_MM`; the result is then snapped
    onto the surface (``z = h(X(z), Y(z))``) where the crossing is continuous, which makes flat
    faces exact.
    """
    lo, flo, hi, fhi = lo.copy(), flo.copy(), hi.copy(), fhi.copy()
    out = np.empty(lo.size)
    side = np.zeros(lo.size, dtype=np.int8)
    active = np.flatnonzero(flo == 0.0)
    out[active] = lo[active]
    active = np.flatnonzero(flo != 0.0)
    iteration = 0
    while active.size:
        a_lo, a_hi, a_flo, a_fhi = lo[active], hi[active], flo[active], fhi[active]
        mid = 0.5 * (a_lo + a_hi)
        if bisect_every and iteration % bisect_every == bisect_every - 1:
            zc = mid
        else:
            zc = a_hi - a_fhi * (a_hi - a_lo) / (a_fhi - a_flo)
            bad = ~((zc > a_lo) & (zc < a_hi))
            zc[bad] = mid[bad]
        fc = f(zc, idx[active])
        neg = fc <= 0.0
        pos = ~neg
        i_neg, i_pos = active[neg], active[pos]
        # Illinois: the end kept twice in a row has its f halved.
        fhi[i_neg[side[i_neg] == -1]] *= 0.5
        flo[i_pos[side[i_pos] == 1]] *= 0.5
        lo[i_neg], flo[i_neg], side[i_neg] = zc[neg], fc[neg], -1
        hi[i_pos], fhi[i_pos], side[i_pos] = zc[pos], fc[pos], 1
        converged = np.abs(fc) <= HIT_TOLERANCE_MM
        out[active[converged]] = zc[converged]
        narrow = ~converged & (hi[active] - lo[active] <= HIT_TOLERANCE_MM)
        out[active[narrow]] = lo[active[narrow]]
        active = active[~(converged | narrow)]
        iteration += 1
        if iteration > 500:
            raise RuntimeError("first-hit search did not converge")  # pragma: no cover
    # Snap onto the surface where the crossing is continuous (flat faces become exact).
    surface = out - f(out, idx)
    snap = np.abs(surface - out) <= 1e-6
    return np.where(snap, surface, out)


def _shadowed(rig: Rig, scene: Scene, X: FloatArray, Y: FloatArray, z: FloatArray) -> BoolArray:
    """True where the segment from the hit point (X, Y, z) to P passes under the height field.

    The segment is ``s (X, Y)`` at height ``zeta = L - s (L - z)``, s from 1 down to the value
    at ``z_max``; it is sampled every :data:`MARCH_STEP_MM` sideways over each footprint box.
    """
    L = rig.L_mm
    z_max = scene.z_max_mm
    shadow = np.zeros(z.shape, dtype=bool)
    boxes = scene.footprints_mm
    below = np.flatnonzero(z < z_max - SHADOW_EPS_MM)
    if below.size == 0 or not boxes:
        return shadow
    if scene.smooth:
        # No occlusion is possible where the surface is flatter than every light ray.
        far = max(math.hypot(max(abs(x0), abs(x1)), max(abs(y0), abs(y1))) for x0, x1, y0, y1 in boxes)
        if scene.max_slope * far / (L - z_max) < 1.0:
            return shadow
    Xb, Yb, zb = X[below], Y[below], z[below]
    s_top = (L - z_max) / (L - zb)
    for box in boxes:
        s_lo, s_hi = _slab(Xb, Yb, box)
        np.maximum(s_lo, s_top, out=s_lo)
        inside_now = s_hi >= 1.0
        np.minimum(s_hi, 1.0, out=s_hi)
        sel = np.flatnonzero((s_lo <= s_hi) & ~shadow[below])
        if sel.size == 0:
            continue
        Xc, Yc, zc = Xb[sel], Yb[sel], zb[sel]
        rho_p = np.hypot(Xc, Yc) / (L - zc)
        dzeta = MARCH_STEP_MM / np.maximum(rho_p, MARCH_STEP_MM / (z_max - zc))
        enter = L - s_hi[sel] * (L - zc)
        leave = L - s_lo[sel] * (L - zc)
        # From the hit point itself start one step up; from outside the box, at its entry.
        zeta = np.where(inside_now[sel], zc + dzeta, enter)
        zeta_prev = np.where(inside_now[sel], zc, np.maximum(enter - dzeta, zc))
        every = np.arange(sel.size)

        def height_at(
            zv: FloatArray,
            rows: npt.NDArray[np.intp],
            Xc: FloatArray = Xc,
            Yc: FloatArray = Yc,
            zc: FloatArray = zc,
        ) -> FloatArray:
            scale = (L - zv) / (L - zc[rows])
            return scene.height_mm(Xc[rows] * scale, Yc[rows] * scale)

        h_prev = height_at(zeta_prev, every)
        active = np.flatnonzero(zeta <= leave)
        while active.size:
            zt = np.minimum(zeta[active], leave[active])
            h = height_at(zt, active)
            occluded = h > zt + SHADOW_EPS_MM
            # A wall rising towards P between two samples: find it and test its top edge.
            # (only where the rise reaches above the previous sample of the segment)
            rise = h - h_prev[active]
            rising = np.flatnonzero(~occluded & (rise > MARCH_STEP_MM) & (h > zeta_prev[active]))
            if rising.size:
                rows = active[rising]
                occluded[rising] = _wall_occludes(height_at, rows, zeta_prev[rows], zt[rising], h_prev[rows], h[rising])
            shadow[below[sel[active[occluded]]]] = True
            zeta_prev[active] = zt
            h_prev[active] = h
            keep = active[~occluded & (zt < leave[active])]
            zeta[keep] += dzeta[keep]
            active = keep
    return shadow


def _clipped_edge(
    f: Callable[[FloatArray, npt.NDArray[np.intp]], FloatArray],
    idx: npt.NDArray[np.intp],
    z_low: FloatArray,
    z_high: FloatArray,
    h_at_high: FloatArray,
    h_at_low: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Locate where the height under a camera ray drops from ``h_at_high`` to ``h_at_low``.

    Bisection (to about 1e-12 mm) on ``h > (h_at_high + h_at_low) / 2`` between the ray heights
    ``z_low < z_high`` finds a wall; golden-section searches find where a steep smooth rim (a
    sphere's silhouette) comes closest. Returns the ray height of the lowest ``f`` found and f
    there (``f <= 0``: the ray passed under the surface, so it hit it above that point).
    """
    level = 0.5 * (h_at_high + h_at_low)
    lo, hi = z_low.copy(), z_high.copy()
    for _ in range(48):
        mid = 0.5 * (lo + hi)
        high = mid - f(mid, idx) > level
        hi = np.where(high, mid, hi)
        lo = np.where(high, lo, mid)
    # hi is on the high side of the drop; the ray may also dip under a steep smooth rim
    # just before it (a sphere's silhouette): minimise f between the drop and z_high.
    z_best, f_best = hi, f(hi, idx)
    for a in (hi, z_low):
        z_try = _golden_min(lambda zv: f(zv, idx), a, z_high)
        f_try = f(z_try, idx)
        better = f_try < f_best
        z_best, f_best = np.where(better, z_try, z_best), np.where(better, f_try, f_best)
    return z_best, f_best


def _golden_min(func: Callable[[FloatArray], FloatArray], a: FloatArray, b: FloatArray, iters: int = 40) -> FloatArray:
    """Golden-section search for the minimum of ``func`` on each interval [a, b] (vectorised)."""
    ratio = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = a.copy(), b.copy()
    c = b - ratio * (b - a)
    e = a + ratio * (b - a)
    fc, fe = func(c), func(e)
    for _ in range(iters):
        left = fc < fe
        b = np.where(left, e, b)
        a = np.where(left, a, c)
        c_new = np.where(left, b - ratio * (b - a), e)
        e_new = np.where(left, c, a + ratio * (b - a))
        c, e = c_new, e_new
        f_new = func(np.where(left, c, e))
        fc, fe = np.where(left, f_new, fe), np.where(left, fc, f_new)
        # keep the carried-over value on the other side
    return 0.5 * (a + b)


def _wall_occludes(
    height_at: Callable[[FloatArray, npt.NDArray[np.intp]], FloatArray],
    rows: npt.NDArray[np.intp],
    zeta_a: FloatArray,
    zeta_b: FloatArray,
    h_a: FloatArray,
    h_b: FloatArray,
) -> BoolArray:
    """Locate where the height field rises from ``h_a`` to ``h_b`` between two shadow samples.

    Bisection (to about 1e-12 mm) on ``h > (h_a + h_b) / 2`` along the segment; the segment is
    occluded when the top of that rise stands above it. Exact for vertical walls.
    """
    level = 0.5 * (h_a + h_b)
    lo, hi = zeta_a.copy(), zeta_b.copy()
    for _ in range(48):
        mid = 0.5 * (lo + hi)
        high = height_at(mid, rows) > level
        hi = np.where(high, mid, hi)
        lo = np.where(high, lo, mid)
    # Also the highest point of a steep smooth rim just after the rise (a sphere's terminator).
    occluded = height_at(hi, rows) > hi + SHADOW_EPS_MM
    for a in (hi, zeta_a):
        best = _golden_min(lambda zv: zv - height_at(zv, rows), a, zeta_b)
        occluded |= height_at(best, rows) > best + SHADOW_EPS_MM
    return occluded


def crossed_rig_truth(
    rendered: RenderedStack, rig: Rig, projector_width: int, projector_height: int
) -> tuple[FloatArray, FloatArray]:
    """True projector coordinates (u, v) of a render of the paper's crossed-axes virtual rig.

    ``u = l * width / nlp - 0.5`` from the true light code ``l`` of each pixel
    (:attr:`RenderedStack.codes`, the inverse of ``l = (u + 0.5) nlp / width``).
    ``v``: the projector of the paper's rig sits at P = (0, 0, L), beside the camera at
    C = (d, 0, L) along X, so projector rows are epipolar with camera rows: a point (X, Y, z)
    projects from P onto R at ``Y_R = Y L / (L - z)``, which for the point seen by camera
    row k equals the row's ordinate on R, ``Y_A = (k + 0.5 - H/2) FW / W``. We define
    ``v = (Y_R / FH + 0.5) * height - 0.5`` with ``FH = FW H / W`` the camera field's height on
    R: the camera field's rows span the projector rows. Both are NaN where the pixel is not lit.

    Returns
    -------
    u, v : (H, W) float64 arrays, projector units
    """
    codes = rendered.codes
    H, W = codes.shape
    u = codes * (projector_width / rig.nlp) - 0.5
    fw_mm = rig.fw_mm
    pitch = fw_mm / W
    y_a = (np.arange(H) + 0.5 - H / 2) * pitch
    field_h = fw_mm * H / W
    v_row = (y_a / field_h + 0.5) * projector_height - 0.5
    v = np.where(np.isfinite(codes), v_row[:, None], np.nan)
    return u, v
