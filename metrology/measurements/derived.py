"""Result files of a measurement: stored once (height maps, points), the rest derived on request.

A measurement job stores ``height.npy``, its points (``points.npz``, the measured pixels' points
and a bit mask: :mod:`metrology.core.io.points`; dense ``(H, W, 3)`` ``.npy`` files stored before
are read too), ``gray_only_height.npy`` and ``sigma.npy`` (float32, the only copies of the data)
and its statistics. Every reader of the points (the ``points.npy`` download, meshes, figures,
acceptance) reads them through :func:`measurement_points`, which returns the dense ``(H, W, 3)``
float32 map bit for bit as measured. The TIFF height map and
the PLY, STL and OBJ meshes are functions of those and the rig's model, built when first asked
for: meshes are streamed while they are generated (the PLY header leaves before the vertex
normals are computed) and written to a bounded cache in the media storage
(:class:`~metrology.measurements.derived_cache.DerivedFileCache`, ``GCPS_MESH_CACHE_BYTES``) that
later requests read. Measurements stored before points were stored take their points from the
heights and the model (:func:`measurement_points`); those stored before this scheme keep their
stored mesh and TIFF files, which are served as they are.
"""

from __future__ import annotations

import hashlib
import io
import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np
from django.conf import settings
from django.core.files.storage import default_storage
from django.db.models.fields.files import FieldFile

from metrology.measurements.derived_cache import DerivedFileCache
from metrology.measurements.models import RESULT_FILES, Measurement

DERIVED_FILES: tuple[str, ...] = ("height.tiff", "mesh.ply", "mesh.stl", "mesh.obj")
"""Result files built from the stored height map on request (and ``points.npy`` where the heights
give the points: :func:`points_follow_from_heights`)."""

STORED_FILES: tuple[str, ...] = ("height.npy", "gray_only_height.npy", "sigma.npy", "points.npy")
"""Result files a measurement job stores."""

CACHE_PREFIX = "derived"
"""Folder of the media storage that holds the cache of derived files."""

DERIVED_VERSION = 1
"""Bumped when a derived file's content changes, so cached copies of the old content are not served."""


@dataclass(frozen=True)
class ResultFile:
    """One result file to send: a file to open (``path`` or ``stored``) or ``chunks`` to stream."""

    filename: str
    path: Path | None = None
    stored: FieldFile | None = None
    chunks: Iterator[bytes] | None = None

    def open(self) -> IO[bytes] | FieldFile:
        """The file opened for reading in binary mode (``path`` first, else ``stored``); not for ``chunks``."""
        if self.path is not None:
            return self.path.open("rb")
        if self.stored is None:
            raise ValueError(f"{self.filename} is streamed from chunks, it has no file to open")
        return self.stored.open("rb")


def derived_cache() -> DerivedFileCache | None:
    """The cache of derived files in the default storage; None if the storage has no local folder."""
    try:
        root = Path(default_storage.path(CACHE_PREFIX))
    except NotImplementedError:
        return None
    return DerivedFileCache(root, settings.GCPS_MESH_CACHE_BYTES)


def available_files(measurement: Measurement) -> list[str]:
    """Names of the result files a measurement can serve now (none until its height map is stored)."""
    stored = [name for name, field in RESULT_FILES.items() if getattr(measurement, field)]
    if not measurement.height_npy:
        return stored
    derived = [*DERIVED_FILES, *(["points.npy"] if points_follow_from_heights(measurement) else [])]
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


def cache_name(measurement: Measurement, filename: str) -> str:
    """The cache file name of ``filename`` of ``measurement``: keyed by the stored height map and rig values."""
    key = json.dumps(
        [measurement.height_npy.name, measurement.rig_values, DERIVED_VERSION], sort_keys=True, default=str
    )
    digest = hashlib.sha256(key.encode()).hexdigest()[:16]
    stem, ext = filename.rsplit(".", 1)
    return f"measurement-{measurement.pk}-{stem}-{digest}.{ext}"


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


def open_result_file(measurement: Measurement, filename: str) -> ResultFile | None:
    """The result file ``filename`` of ``measurement``: stored, cached, or built now; None if not available.

    A mesh that is not cached is returned as ``chunks`` that generate it (and fill the cache as
    they are consumed); a missing TIFF is written to the cache first (about 50 ms at 1280x1024).
    """
    field = RESULT_FILES[filename]
    stored = getattr(measurement, field)
    if stored and filename == "points.npy":  # stored compactly: sent as the dense map
        return ResultFile(filename, chunks=npy_chunks(measurement_points(measurement)))
    if stored:
        return ResultFile(filename, stored=stored)
    derived_points = filename == "points.npy" and points_follow_from_heights(measurement)
    if not derived_points and (filename not in DERIVED_FILES or not measurement.height_npy):
        return None
    cache = derived_cache()
    name = cache_name(measurement, filename)
    if cache is not None:
        hit = cache.get(name)
        if hit is not None:
            return ResultFile(filename, path=hit)
    if filename == "height.tiff":
        return _tiff(measurement, cache, name)
    if derived_points:
        return _points(measurement, cache, name)
    return ResultFile(filename, chunks=_mesh_chunks(measurement, filename, cache, name))


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


def _tiff(measurement: Measurement, cache: DerivedFileCache | None, name: str) -> ResultFile:
    import tempfile

    from metrology.core.io import write_height_tiff

    z = _heights(measurement)
    if cache is None:
        with tempfile.TemporaryDirectory(prefix="gcps-tiff-") as tmp:
            path = Path(tmp) / "height.tiff"
            write_height_tiff(z, path)
            data = path.read_bytes()
        return ResultFile("height.tiff", chunks=iter([data]))
    with cache.store(name, suffix=".tiff") as tmp_path:
        write_height_tiff(z, tmp_path)
    cached = cache.get(name)
    if cached is None:  # evicted at once (a cache smaller than the file): serve a fresh copy
        return _tiff(measurement, None, name)
    return ResultFile("height.tiff", path=cached)


def _points(measurement: Measurement, cache: DerivedFileCache | None, name: str) -> ResultFile:
    """``points.npy`` of a measurement whose points follow from its heights: ``(H, W, 3)`` float32 mm,
    the same array a job stores for other models (:func:`measurement_points`)."""

    points = measurement_points(measurement)
    if cache is None:
        buffer = io.BytesIO()
        np.save(buffer, points)
        return ResultFile("points.npy", chunks=iter([buffer.getvalue()]))
    with cache.store(name, suffix=".npy") as tmp_path, open(tmp_path, "wb") as out:
        np.save(out, points)
    cached = cache.get(name)
    if cached is None:  # evicted at once (a cache smaller than the file): serve a fresh copy
        return _points(measurement, None, name)
    return ResultFile("points.npy", path=cached)


def _mesh_chunks(measurement: Measurement, filename: str, cache: DerivedFileCache | None, name: str) -> Iterator[bytes]:
    from metrology.core.geometry import model_from_dict
    from metrology.core.mesh import GridMesh, mesh_file_chunks, surface_mesh

    def build() -> GridMesh:
        z = _heights(measurement)
        return surface_mesh(model_from_dict(measurement.rig_values), z, points_mm=measurement_points(measurement, z))

    chunks = mesh_file_chunks(build, filename.rsplit(".", 1)[1])
    return chunks if cache is None else cache.fill(name, chunks)


def clear_cache() -> None:
    """Remove every cached derived file (they are rebuilt on request)."""
    cache = derived_cache()
    if cache is not None:
        cache.clear()
