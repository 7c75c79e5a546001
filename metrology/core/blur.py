"""The camera's blur, estimated from a reference capture, and the phase bias it causes.

A symmetric blur of variance ``s2`` (camera defocus plus the pixel's own area) applied to
fringes ``b cos(phi(x))`` multiplies their visibility by ``exp(-s2 phi'^2 / 2)`` and shifts
their phase by ``s2 phi'' / 2`` to first order. In light codes (``phi = pi/2 l``), a blurred
capture decodes to ``l + s2 / 2 * laplacian(l)``: on a plane the code is almost linear and
nothing moves, but on curved surfaces (a sphere's flanks) heights are biased by tens of
micrometres at a blur of 0.7 px.

The reference plane carries the information needed to undo this: the crossed-axes geometry
makes its fringe frequency vary across the field (paper, Eq. 14), so fitting
``ln V = ln V0 - s2 k^2 / 2`` to its visibility ``V = B / 2A`` against the local
frequency ``k = (pi/2) dl/dx`` gives ``s2`` without any extra capture.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from metrology.core.tiling import nested_threads, run_tiled

# Savitzky-Golay (5 points, quadratic): second derivative, and smoothing across it
_SECOND_DERIVATIVE = (np.array([2, -1, -2, -1, 2], np.float64) / 7).astype(np.float32)
_SMOOTHING = (np.array([-3, 12, 17, 12, -3], np.float64) / 35).astype(np.float32)
# d2/dx2 smoothed along y plus d2/dy2 smoothed along x, as one 5x5 kernel (rows are y)
_LAPLACIAN_5X5 = (np.outer(_SMOOTHING, _SECOND_DERIVATIVE) + np.outer(_SECOND_DERIVATIVE, _SMOOTHING)).astype(
    np.float32
)
_BASELINE_PX = 4  # half-width of the difference that measures the reference's code slope
_EDGE_PX = 8  # columns left out at each side of the field


def estimate_blur_variance(codes: npt.ArrayLike, visibility: npt.ArrayLike) -> float:
    """Blur variance (px^2) from a reference capture's visibility against fringe frequency.

    Parameters
    ----------
    codes : (H, W) float array
        Decoded codes of the reference plane, code units, NaN where invalid.
    visibility : (H, W) float array
        Fringe visibility ``B / 2A`` of the same capture (any constant multiple works).

    Returns
    -------
    s2 : float
        Variance of the effective blur (camera point spread and pixel area), px^2, >= 0.
        0.083 px^2 (a box of one pixel) for a sharp camera.

    Raises
    ------
    ValueError
        If fewer than 500 valid pixels (on every other row) are available or the frequencies do not vary enough
        to fit (a field narrower than a few fringes).
    """
    l = np.asarray(codes, dtype=np.float32)
    v = np.asarray(visibility, dtype=np.float32)
    if l.shape != v.shape or l.ndim != 2:
        raise ValueError(f"codes and visibility must be two (H, W) arrays of one shape, got {l.shape}, {v.shape}")
    width = l.shape[1]
    b = _BASELINE_PX
    if width <= 2 * _EDGE_PX:
        raise ValueError(f"too few valid reference pixels to estimate the blur (the field is {width} px wide)")
    # every other row: plenty of samples, half the work; columns _EDGE_PX .. width - _EDGE_PX
    rows = slice(None, None, 2)
    centre = slice(_EDGE_PX, width - _EDGE_PX)
    slope = l[rows, _EDGE_PX + b : width - _EDGE_PX + b] - l[rows, _EDGE_PX - b : width - _EDGE_PX - b]
    k2 = np.square(slope, out=slope)
    k2 *= np.float32((np.pi / 2 / (2 * b)) ** 2)  # (pi/2 dl/dx)^2, rad^2 per px^2
    with np.errstate(divide="ignore", invalid="ignore"):
        log_v = np.log(v[rows, centre])
    ok = np.isfinite(k2)
    ok &= np.isfinite(log_v)
    if ok.sum() < 500:
        raise ValueError(f"too few valid reference pixels to estimate the blur ({int(ok.sum())})")
    x = k2[ok].astype(np.float64)
    y = log_v[ok].astype(np.float64)
    if x.max() - x.min() < 0.01:
        raise ValueError("the reference's fringe frequency varies too little across the field to estimate the blur")
    x -= x.mean()
    gradient = float(np.dot(x, y - y.mean()) / np.dot(x, x))  # least-squares line ln V = a + gradient k^2
    return max(0.0, -2.0 * gradient)


def code_laplacian(codes: npt.ArrayLike) -> np.ndarray:
    """Smoothed Laplacian of a code map (5x5 Savitzky-Golay), code units per px^2.

    Parameters
    ----------
    codes : (H, W) float array, NaN where invalid

    Returns
    -------
    (H, W) float32 array
        ``d2l/dx2 + d2l/dy2``; NaN where the 5x5 window holds an invalid pixel.
    """
    return _block_laplacian(np.asarray(codes, dtype=np.float32), top=True, bottom=True)


def _block_laplacian(l: np.ndarray, *, top: bool, bottom: bool) -> np.ndarray:
    """:func:`code_laplacian` of a block of rows ``l`` (float32): NaN on its two edge columns each
    side, and on its two first (last) rows only where ``top`` (``bottom``) says they are the
    frame's; elsewhere those rows are wrong (the block's zero border) and left for the caller to drop."""
    laplacian: np.ndarray = cv2.filter2D(l, cv2.CV_32F, _LAPLACIAN_5X5, borderType=cv2.BORDER_CONSTANT)
    if top:
        laplacian[:2] = np.nan
    if bottom:
        laplacian[-2:] = np.nan
    laplacian[:, :2] = laplacian[:, -2:] = np.nan
    return laplacian


def blur_bias_exceeds(
    codes: np.ndarray,
    blur_variance_px2: float,
    max_bias_codes: float,
    out: np.ndarray,
    laplacian_out: np.ndarray | None = None,
) -> np.ndarray:
    """Where the blur's first-order bias ``|s2 / 2 * laplacian(l)|`` exceeds ``max_bias_codes``.

    :func:`correct_blur_bias` removes ``s2 / 2 * laplacian(l)`` with the Laplacian averaged
    over 1.5 px: right where the code surface is smooth over the blur's support, where that
    bias is a few thousandths of a code (below 0.01, noise included, at 1.5 grey levels on the
    virtual rig's spheres, face, flowerpot and the treads of steps). At a crease of the code
    surface -- a riser seen edge-on between two treads, the code's slope tripling within a
    pixel -- the blur mixes codes from both sides of the crease, the bias reaches 0.03 code
    (0.4 mm) at the pixels beside it, and the expansion behind the correction fails: its
    higher terms are as large as the first, and the averaged Laplacian, of opposite signs on
    the two sides, cancels. A depth step whose code jump is too small to be seen as one (a
    few tenths of a code: a 5 mm step) looks the same to the Laplacian, which peaks a pixel
    either side of the step. Such pixels cannot be corrected; they are marked here to be
    dropped.

    Parameters
    ----------
    codes : (h, W) float32 array
        A block of rows of decoded codes, code units, NaN where invalid.
    blur_variance_px2 : float
        The camera blur's variance ``s2``, px^2 (:func:`estimate_blur_variance`), >= 0.
    max_bias_codes : float
        Largest bias accepted, code units, > 0.
    out : (h, W) bool array
        Receives the mask: True where the bias exceeds the bound. False where the 5x5 window
        holds an invalid pixel and on the two rows and columns at each edge of the block, whose
        window leaves it: a caller working on tiles gives each two rows of context.
    laplacian_out : (h, W) float32 array, optional
        Scratch for the Laplacian (the 5x5 Savitzky-Golay one of :func:`code_laplacian`).

    Returns
    -------
    out
    """
    if blur_variance_px2 <= 0 or max_bias_codes <= 0:
        out[...] = False
        return out
    l = np.asarray(codes, dtype=np.float32)
    laplacian: np.ndarray = cv2.filter2D(
        l, cv2.CV_32F, _LAPLACIAN_5X5, dst=laplacian_out, borderType=cv2.BORDER_CONSTANT
    )
    np.abs(laplacian, out=laplacian)
    np.greater(laplacian, np.float32(2 * max_bias_codes / blur_variance_px2), out=out)  # NaN: False
    out[:2] = out[-2:] = False
    out[:, :2] = out[:, -2:] = False
    return out


def correct_blur_bias(codes: np.ndarray, blur_variance_px2: float, threads: int | None = None) -> np.ndarray:
    """Remove the blur's phase bias: ``l - s2 / 2 * laplacian(l)``, in place where defined.

    Parameters
    ----------
    codes : (H, W) float32 array
        Decoded codes, NaN where invalid; corrected in place.
    blur_variance_px2 : float
        Effective blur variance, px^2 (:func:`estimate_blur_variance`).
    threads : int, optional
        Threads over row tiles (:func:`~metrology.core.tiling.run_tiled`); the result does not
        depend on them: each tile is computed from its rows and :data:`_HALO_ROWS` rows either
        side, more than the Laplacian's and the smoothing's reach together, bit for bit as on the
        whole frame.

    Returns
    -------
    codes : the same array. Pixels whose 5x5 window holds an invalid pixel are left as they are.
    """
    if blur_variance_px2 < 0:
        raise ValueError(f"blur_variance_px2 must be >= 0, got {blur_variance_px2}")
    if blur_variance_px2 == 0:
        return codes
    height, width = codes.shape
    correction = np.empty((height, width), np.float32)
    scale = np.float32(blur_variance_px2 / 2)

    def compute(rows: slice) -> None:  # reads codes only: the tiles' halos overlap
        lo, hi = max(0, rows.start - _HALO_ROWS), min(height, rows.stop + _HALO_ROWS)
        block = np.asarray(codes[lo:hi], dtype=np.float32)
        smoothed = _smooth_and_extend(_block_laplacian(block, top=lo == 0, bottom=hi == height))
        np.multiply(smoothed[rows.start - lo : rows.stop - lo], scale, out=correction[rows])

    def subtract(rows: slice) -> None:
        codes[rows] -= correction[rows]  # NaN codes stay NaN

    threads = nested_threads(threads)  # one on a thread of the pool itself
    run_tiled(compute, height, width, threads)
    run_tiled(subtract, height, width, threads)
    return codes


_SMOOTHING_SIGMA_PX = 1.5
_HALO_ROWS = 8
"""Rows read beyond a tile by :func:`correct_blur_bias`: the 5x5 Laplacian's border spoils 2 rows at
a block's edge and the Gaussian of sigma 1.5 px (OpenCV's 13-tap float kernel) carries them 6 rows
further, so 8 rows give every thread count the whole frame's result bit for bit (7 do not; 16, the
earlier margin, cost 16 % more)."""
_MIN_WEIGHT = 0.05


def _smooth_and_extend(laplacian: np.ndarray) -> np.ndarray:
    """Normalized Gaussian average of the defined Laplacian values, 0 where none is near.

    The Laplacian varies slowly, so averaging it (sigma 1.5 px) removes the noise it would
    otherwise add to the heights (~4 %), and carries it into the pixels next to holes and
    edges whose own 5x5 window was incomplete.
    """
    defined = np.isfinite(laplacian)
    weights: np.ndarray = np.empty(laplacian.shape, np.float32)
    np.copyto(weights, defined)
    weights = cv2.GaussianBlur(weights, (0, 0), _SMOOTHING_SIGMA_PX, dst=weights)
    cv2.patchNaNs(laplacian, 0.0)
    values: np.ndarray = cv2.GaussianBlur(laplacian, (0, 0), _SMOOTHING_SIGMA_PX, dst=laplacian)
    np.maximum(weights, np.float32(_MIN_WEIGHT), out=weights)
    values /= weights
    return values
