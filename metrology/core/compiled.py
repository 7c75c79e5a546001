"""The core's compiled kernels (numba, ``cache=True``: machine code kept next to each module) and
:func:`warm_all`, which loads every one, compiling it where its cache is missing or stale.

A process pays numba's first call of a kernel: about 0.3 s to load it from the cache, 1 s to
compile it (a fresh installation). Celery workers warm :data:`KERNEL_MODULES` as they start
(:func:`metrology.jobs.handlers.preload_job_code`), so no job pays it; the stereo model's kernels
load on first use. ``python -m metrology.core.compiled`` compiles every kernel, the stereo model's
included (:func:`warm_stereo`): the test script runs it once before its parallel workers start,
so that they do not each compile the same kernels (a clean clone's stereo kernels alone take
about 11 s of CPU). ``gcps`` commands never import numba for these: where it is not loaded the
kernels' numpy twins run (same numbers), by one rule (:func:`metrology.core.kernel_choice.use_compiled`).
"""

from __future__ import annotations

import importlib

KERNEL_MODULES = (
    "metrology.core.decode_kernels",
    "metrology.core.codecs.kernels",
    "metrology.core.geometry.pinhole_kernels",
    "metrology.core.simulate.kernels",
)
"""Modules of compiled kernels with a ``warm()``."""

STEREO_KERNEL_MODULES = (
    "metrology.core.geometry.stereo_kernels",
    "metrology.core.geometry.match_2d_kernels",
)
"""The stereo model's kernel modules, compiled by :func:`warm_stereo` through a measurement."""


def warm_all() -> None:
    """Load (or compile) every kernel of :data:`KERNEL_MODULES`."""
    for name in KERNEL_MODULES:
        importlib.import_module(name).warm()


def warm_stereo() -> None:
    """Load (or compile) the kernels of :data:`STEREO_KERNEL_MODULES` by measuring a tiny virtual
    capture (two 40x30 distorted cameras, a calibrated 160x100 projector, a codec of both axes):
    with the epipolar and the 2-D match, each with and without sigma. These are a measurement's own
    calls, so they compile the signatures (dtypes, dimensions, layouts) measurements use; the
    kernels' many arguments make calls on empty arrays (as the other modules' ``warm()``) easy to
    get subtly wrong, and a wrong one compiles in vain."""
    from metrology.core.codecs import codec_from_dict
    from metrology.core.geometry.base import GeometryOptions
    from metrology.core.geometry.pinhole import PinholeCamera, PinholeProjector, look_at_rig
    from metrology.core.geometry.stereo import StereoProjector, StereoRig
    from metrology.core.measure import MeasureOptions, measure
    from metrology.core.scenes import make_scene
    from metrology.core.simulate.cast import ScenePlacement
    from metrology.core.simulate.stereo import ProjectorPlacement, render_stereo_capture

    width, height, distance = 160, 100, 400.0
    intrinsics = ((60.0, 0.0, 19.6), (0.0, 60.0, 14.4), (0.0, 0.0, 1.0))
    camera = PinholeCamera(40, 30, intrinsics, (-0.1, 0.02, 0.0005, -0.0003, 0.0))
    lens = PinholeProjector(
        width, height, ((190.0, 0.0, 80.2), (0.0, 190.0, 49.7), (0.0, 0.0, 1.0)), (0.03, 0, 0, 0, 0)
    )
    pose1 = look_at_rig(camera, lens, (100.0, 3.0, 5.0), (0.0, 0.0, distance))
    pose_p = look_at_rig(camera, lens, (50.0, -20.0, 0.0), (0.0, 0.0, distance))
    projector = StereoProjector(width, height, K=lens.K, dist=lens.dist, R=pose_p.R, T=pose_p.T)
    rig = StereoRig(camera0=camera, camera1=camera, R=pose1.R, T=pose1.T, projector=projector)
    axes: dict[str, object] = {}
    first = 0
    for axis in ("u", "v"):  # 4-step phase of 16 px, gray code of 16-px words (16 x 2^4 >= 160 + 1)
        phase = {
            "frames": list(range(first, first + 4)),
            "period": 16.0,
            "shift": 1,
            "origin": -0.5,
            "waveform": "sine",
        }
        gray = {"frames": list(range(first + 4, first + 8)), "word": 16.0, "order": "msb_first", "origin": -0.5}
        axes[axis] = {"phase": [phase], "gray": gray}
        first += 8
    spec = {
        "codec": "gcps-codec/1",
        "frames": first + 2,
        "projector": {"width": width, "height": height},
        "white": [first],
        "black": [first + 1],
        "axes": axes,
    }
    codec = codec_from_dict(spec)
    lighting = ProjectorPlacement(projector=lens, R=pose_p.R, T=pose_p.T)
    placement = ScenePlacement.facing_camera(distance)
    capture = render_stereo_capture(rig, make_scene("plane", z_mm=0.0), codec, placement=placement, projector=lighting)
    for match in ("epipolar", "2d"):
        for sigma in (False, True):
            options = MeasureOptions(geometry=GeometryOptions(match=match), sigma=sigma)
            measure(rig, capture.images, codec, options=options)


def main() -> None:
    """``python -m metrology.core.compiled``: :func:`warm_all` and :func:`warm_stereo`, in two
    processes where there are two cores (each about 10 s of CPU on a clean clone; numba writes a
    cache file per kernel and signature, and the two never compile the same kernel)."""
    import os
    from concurrent.futures import ProcessPoolExecutor

    if (os.cpu_count() or 1) < 2:
        warm_all()
        warm_stereo()
        return
    with ProcessPoolExecutor(max_workers=2) as pool:
        for done in [pool.submit(warm_all), pool.submit(warm_stereo)]:
            done.result()


if __name__ == "__main__":
    main()
