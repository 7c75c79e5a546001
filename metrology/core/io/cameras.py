"""The layout of a capture of several cameras (a stereo rig's, docs/stereo.md).

One folder or zip holds a sub-folder per camera, ``cam0/``, ``cam1/`` ..., each with the codec's
frames exactly as a single-camera capture holds them (natural sort, the codec's ``files`` pattern
applied inside each; frame files may be symbolic links, followed), and optionally ``codec.json`` at
the top (the multi-exposure form, ``exp0/`` ... beside ``exposures.json``, is laid out alike).
Reading it: :func:`metrology.core.codecs.stack.read_camera_stacks`.
"""

from __future__ import annotations

CAMERA_FOLDER_PREFIX = "cam"
"""Camera ``i``'s frames lie in ``cam{i}/``."""


def camera_folder(index: int) -> str:
    """The sub-folder of camera ``index`` (``cam0``, ``cam1``...)."""
    if isinstance(index, bool) or not isinstance(index, int) or index < 0:
        raise ValueError(f"camera index must be a non-negative integer, got {index!r}")
    return f"{CAMERA_FOLDER_PREFIX}{index}"


def camera_folders(count: int) -> tuple[str, ...]:
    """The sub-folders of ``count`` cameras, camera 0 first."""
    return tuple(camera_folder(i) for i in range(count))
