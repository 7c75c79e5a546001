"""Result files of a measurement: stored once (height maps, points), the rest derived by a job.

A measurement job stores ``height.npy``, its points (``points.npz``, the measured pixels' points
and a bit mask: :mod:`metrology.core.io.points`; dense ``(H, W, 3)`` ``.npy`` files stored before
are read too), ``gray_only_height.npy`` and ``sigma.npy`` (float32, the only copies of the data),
``exposure.npy`` for a multi-exposure object (uint8, carried by the PLY as the vertex property
``exposure``), ``pairs.npy`` for a stereo rig (uint8 bits, the PLY's vertex property ``pairs``) and its
statistics. Every reader of the points (the ``points.npy`` download, meshes, figures,
acceptance) reads them through :func:`measurement_points`, which returns the dense ``(H, W, 3)``
float32 map bit for bit as measured. The TIFF height map, the PLY, STL and OBJ meshes (and
``points.npy`` where the heights give the points) are functions of those and the rig's model:
the first request for one queues a *derived file* job (``Job.Kind.DERIVED_FILE``,
:func:`build_derived_file`) that writes it to a temporary folder and uploads it to the storage's
``derived/`` folder under a name keyed by the stored height map and the rig values
(:func:`derived_name`); later requests are served from the storage
(:mod:`metrology.file_serving`: ranges, X-Accel-Redirect, presigned URLs). The folder is bounded
(:class:`~metrology.measurements.derived_cache.DerivedFiles`, ``GCPS_MESH_CACHE_BYTES``).
Measurements stored before this scheme keep their stored mesh and TIFF files, served as they are.
Nothing here uses a local path of the storage: it may be an S3 bucket.
"""

from __future__ import annotations

import hashlib
import io
import json
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from django.conf import settings
from django.core.files import File
from django.core.files.storage import default_storage
from django.db.models.fields.files import FieldFile

from metrology.measurements.derived_cache import DerivedFiles
from metrology.measurements.models import RESULT_FILES, Measurement, stored_file

DERIVED_FILES: tuple[str, ...] = ("height.tiff", "mesh.ply", "mesh.stl", "mesh.obj")
"""Result files built from the stored height map by a job when first asked for (and ``points.npy`` where the heights
give the points: :func:`points_follow_from_heights`; ``points.e57`` wherever there are points: :func:`has_points`)."""

E57_FILE = "points.e57"
"""The measured points as an ASTM E2807 (E57) file (:func:`metrology.core.io.e57.write_e57`): one scan,
the points in mm in the rig's model frame with the identity pose, each point's camera pixel as its
row and column index, and no intensity (a measurement stores no modulation map)."""

STORED_FILES: tuple[str, ...] = (
    "height.npy",
    "gray_only_height.npy",
    "sigma.npy",
    "points.npy",
    "exposure.npy",
    "pairs.npy",
)
"""Result files a measurement job stores."""

CACHE_PREFIX = "derived"
"""Folder of the media storage that holds the cache of derived files."""

DERIVED_VERSION = 1
"""Bumped when a derived file's content changes, so cached copies of the old content are not served."""


@dataclass(frozen=True)
class ResultFile:
    """One result file to send: a file of the default storage (``name``), or ``chunks`` to stream.

    ``ready`` is False for a derived file that is not built yet: ``name`` is where its job will
    store it (:func:`build_derived_file`).
    """

    filename: str
    name: str | None = None
    chunks: Iterator[bytes] | None = None
    ready: bool = True


def derived_files() -> DerivedFiles:
    """The bounded folder of derived files in the default storage."""
    return DerivedFiles(default_storage, CACHE_PREFIX, settings.GCPS_MESH_CACHE_BYTES)


def available_files(measurement: Measurement) -> list[str]:
    """Names of the result files a measurement can serve now (none until its height map is stored)."""
    stored = [name for name in RESULT_FILES if stored_file(measurement, name)]
    if not measurement.height_npy:
        return stored
    derived = [
        *DERIVED_FILES,
        *(["points.npy"] if points_follow_from_heights(measurement) else []),
        *([E57_FILE] if has_points(measurement) else []),
    ]
    return [name for name in RESULT_FILES if name in stored or name in derived]


def points_follow_from_heights(measurement: Measurement) -> bool:
    """True when the measurement's points are its heights on its model's camera rays (a model with a
    plane of its own; :attr:`metrology.core.measure.Measurement.points_follow_from_heights`), so
    ``points.npy`` is derived from ``height.npy`` when not stored."""
    from metrology.core.geometry import model_from_dict

    if measurement.points_npy or not measurement.height_npy:
        return False
    try:
        return bool(model_from_dict(measurement.rig_values).prepare().has_model_plane)
    except ValueError:
        return False


def has_points(measurement: Measurement) -> bool:
    """True when the measurement has points (stored, or its heights on its model's camera rays)."""
    return bool(measurement.height_npy) and (bool(measurement.points_npy) or points_follow_from_heights(measurement))


def check_buildable(filename: str) -> None:
    """Conflict (409) when the server cannot build ``filename``: an E57 file needs the optional
    ``pye57`` (``pip install 'gcps-lab[e57]'``)."""
    if filename != E57_FILE:
        return
    from metrology.errors import Conflict

    try:
        import pye57  # noqa: F401
    except ImportError:
        raise Conflict(
            "points.e57: this server cannot write E57 files: pye57 is not installed (pip install 'gcps-lab[e57]')"
        ) from None


def cache_name(measurement: Measurement, filename: str) -> str:
    """The cache file name of ``filename`` of ``measurement``: keyed by the stored height map and rig values."""
    key = json.dumps(
        [measurement.height_npy.name, measurement.rig_values, DERIVED_VERSION], sort_keys=True, default=str
    )
    digest = hashlib.sha256(key.encode()).hexdigest()[:16]
    stem, ext = filename.rsplit(".", 1)
    return f"measurement-{measurement.pk}-{stem}-{digest}.{ext}"


def derived_name(measurement: Measurement, filename: str) -> str:
    """The storage name of the derived file ``filename`` of ``measurement`` (``derived/<cache name>``)."""
    return f"{CACHE_PREFIX}/{cache_name(measurement, filename)}"


def _load(field: FieldFile) -> np.ndarray:
    with field.open("rb") as handle:
        return np.load(io.BytesIO(handle.read()), allow_pickle=False)


def _heights(measurement: Measurement) -> np.ndarray:
    return _load(measurement.height_npy)


def measurement_points(measurement: Measurement, z_mm: np.ndarray | None = None) -> np.ndarray:
    """The ``(H, W, 3)`` float32 points of a done measurement, mm, model frame, NaN where not
    measured: the stored points (a stored point map, or the dense ``.npy`` stored before it: bit
    for bit as measured), or, where none are stored, its heights on its model's camera rays.

    Raises
    ------
    ValueError
        When there are no stored points and the model needs the reference plane to place heights
        on its rays (it has no plane of its own).
    """
    if measurement.points_npy:
        from metrology.core.io.points import read_point_map

        with measurement.points_npy.open("rb") as handle:
            return read_point_map(handle.read())
    from metrology.core.geometry import model_from_dict

    prepared = model_from_dict(measurement.rig_values).prepare()
    if not prepared.has_model_plane:
        raise ValueError(f"measurement {measurement.pk} has no stored points")
    z = _heights(measurement) if z_mm is None else z_mm
    return prepared.points_from_heights(z).astype(np.float32)


def is_derived(measurement: Measurement, filename: str) -> bool:
    """True when ``filename`` of ``measurement`` is built by a derived-file job (not stored by its measurement)."""
    if stored_file(measurement, filename) or not measurement.height_npy:
        return False
    if filename == E57_FILE:
        return has_points(measurement)
    return filename in DERIVED_FILES or (filename == "points.npy" and points_follow_from_heights(measurement))


def open_result_file(measurement: Measurement, filename: str) -> ResultFile | None:
    """The result file ``filename`` of ``measurement``: stored, derived (built or not yet), or None if not available.

    Stored files and built derived files are named in the default storage; a derived file not
    built yet comes back with ``ready=False`` (queue :func:`metrology.measurements.services.request_derived_file`);
    compactly stored points are streamed as the dense ``.npy`` (``chunks``).
    """
    stored = stored_file(measurement, filename)
    if stored and filename == "points.npy":  # stored compactly: sent as the dense map
        return ResultFile(filename, chunks=npy_chunks(measurement_points(measurement)))
    if stored:
        return ResultFile(filename, name=stored.name)
    if not is_derived(measurement, filename):
        return None
    name = derived_name(measurement, filename)
    return ResultFile(filename, name=name, ready=default_storage.exists(name))


NPY_CHUNK_BYTES = 1 << 20
"""Bytes per chunk of a streamed ``.npy``."""


def npy_chunks(array: np.ndarray) -> Iterator[bytes]:
    """The bytes of ``numpy.save(file, array)`` for a C-contiguous numeric array, in chunks of at most
    :data:`NPY_CHUNK_BYTES` after the header (no second copy of the array is made)."""
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, np.lib.format.header_data_from_array_1_0(array))
    yield header.getvalue()
    data = np.ascontiguousarray(array).reshape(-1).view(np.uint8)
    for start in range(0, data.size, NPY_CHUNK_BYTES):
        yield data[start : start + NPY_CHUNK_BYTES].tobytes()


def write_derived_file(measurement: Measurement, filename: str, path: Path) -> None:
    """Write the derived file ``filename`` of ``measurement`` (one of :data:`DERIVED_FILES`, or the
    derived ``points.npy``, or ``points.e57``) to the local file ``path``: the TIFF height map (float32, NaN
    kept), a mesh (:func:`metrology.core.mesh.mesh_file_chunks`), the ``(H, W, 3)`` float32 points, mm, or
    the points as E57 (:data:`E57_FILE`)."""
    from metrology.core.geometry import model_from_dict
    from metrology.core.io import write_height_tiff
    from metrology.core.mesh import GridMesh, mesh_file_chunks, surface_mesh

    if filename == "height.tiff":
        write_height_tiff(_heights(measurement), path)
        return
    if filename == "points.npy":
        with open(path, "wb") as out:
            np.save(out, measurement_points(measurement))
        return
    if filename == E57_FILE:
        from metrology.core.io.e57 import write_e57

        write_e57(path, measurement_points(measurement), name=f"GCPS Lab measurement {measurement.pk}")
        return

    def build() -> GridMesh:
        z = _heights(measurement)
        points = measurement_points(measurement, z)
        mesh = surface_mesh(model_from_dict(measurement.rig_values), z, points_mm=points)
        if filename == "mesh.ply" and measurement.exposure_npy:  # the exposure of each vertex
            mesh = mesh.with_exposure(
                _load(measurement.exposure_npy), np.isfinite(z) & np.isfinite(points).all(axis=-1)
            )
        if filename == "mesh.ply" and measurement.pairs_npy:  # a stereo rig: the pairs of each vertex
            mesh = mesh.with_pairs(_load(measurement.pairs_npy), np.isfinite(z) & np.isfinite(points).all(axis=-1))
        return mesh

    with open(path, "wb") as out:
        for chunk in mesh_file_chunks(build, filename.rsplit(".", 1)[1]):
            out.write(chunk)


def build_derived_file(measurement: Measurement, filename: str, save=None) -> str:
    """Build the derived file ``filename`` of ``measurement`` in a temporary folder and upload it to
    the default storage as :func:`derived_name`; returns that name (nothing is built when it is
    already stored). ``save(storage, name, File)`` stores it (a job's ``JobRun.save_file``, so a
    failed attempt removes it); default ``storage.save``. Then the folder is trimmed to
    ``GCPS_MESH_CACHE_BYTES``, keeping this file.
    """
    name = derived_name(measurement, filename)
    if default_storage.exists(name):
        return name
    with tempfile.TemporaryDirectory(prefix="gcps-derived-") as tmp:
        path = Path(tmp) / filename
        write_derived_file(measurement, filename, path)
        with open(path, "rb") as handle:
            content = File(handle, name=filename)
            stored = save(default_storage, name, content) if save else default_storage.save(name, content)
    if stored != name:  # another job stored it first (local storage never overwrites): keep theirs
        default_storage.delete(stored)
    derived_files().trim(keep=name)
    return name


def clear_cache() -> None:
    """Remove every derived file (they are built again when asked for)."""
    derived_files().clear()
