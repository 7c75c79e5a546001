"""Decoded references kept on local disk, so that a second process measuring against the same
reference capture does not decode it again (``gcps measure``).

A :class:`~metrology.core.measure.Reference` is stored in the per-host local cache
(:mod:`metrology.core.local_cache`, kind ``reference``) under one of two keys, each with the rig's
model, the codec, the measurement options and the software version:

- the capture's **files** (:func:`cached_reference_of_files`, what ``gcps measure`` uses): the
  SHA-256 of the files as stored (:func:`~metrology.core.io.digests.capture_files_digest`: the
  compressed PNGs, not the decoded frames) and the reader's options (:func:`files_reference_key`);
  a hit reads no image, a miss reads and decodes them;
- the decoded **frames** (:func:`cached_reference`, for frames already in memory): the SHA-256 of
  the stack's bytes with its shape and dtype (:func:`stack_digest`, :func:`reference_key`).

A different capture, rig, codec, option or version decodes again. What is stored
(:func:`reference_arrays`): the reference's codes (float32), its unreliable-pixel mask packed to
bits (``np.packbits``), the blur variance, and the model's reference surface (and the gray-code
surface of the fused gcps-v1 path) field by field, each array once even where two fields share
it. The model, codec and geometry options come from the caller (they are in the key), so a read
reference passes the measurement's checks.

A failed read or write only costs the decode (the local cache warns, never raises).
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import json
import os
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from metrology.core import local_cache
from metrology.core.codecs.model import Codec
from metrology.core.codecs.stack import ExposureStack
from metrology.core.geometry.base import GeometryModel, ReferenceSurface
from metrology.core.io.digests import capture_files_digest
from metrology.core.measure import MeasureOptions, Reference, prepare_reference
from metrology.core.tiling import map_threads

KIND = "reference"
"""The local cache's sub-folder of decoded references."""

_META = "meta"
_SURFACE_MODULES = "metrology.core.geometry."


def stack_digest(images: npt.ArrayLike | ExposureStack | tuple[np.ndarray, ...]) -> str:
    """SHA-256 (hex) of a stack's shape, dtype and the SHA-256 of each :data:`DIGEST_CHUNK` bytes of
    its frames, in order; of a multi-exposure capture, of each exposure's description (name, time,
    gain, brightness) and its stack's digest, in order; of a capture of several cameras (a tuple of
    stacks), of each camera's stack's digest, in order."""
    if isinstance(images, tuple):
        digest = hashlib.sha256(b"gcps-cameras|")
        for frames in images:
            digest.update(stack_digest(frames).encode())
        return digest.hexdigest()
    if isinstance(images, ExposureStack):
        digest = hashlib.sha256(b"gcps-exposures|")
        for exposure, frames in zip(images.exposures, images.images, strict=True):
            digest.update(json.dumps(exposure.to_dict(), sort_keys=True).encode())
            digest.update(stack_digest(frames).encode())
        return digest.hexdigest()
    stack = np.ascontiguousarray(images)
    data = stack.reshape(-1).view(np.uint8)
    # a hash list: the SHA-256 of every DIGEST_CHUNK bytes, on the pool's threads (hashlib releases
    # the GIL), then of their concatenation: ~2x faster on two cores than one pass, as strong
    chunks = [data[start : start + DIGEST_CHUNK] for start in range(0, data.size, DIGEST_CHUNK)]
    parts = map_threads(lambda chunk: hashlib.sha256(chunk.data).digest(), chunks)
    digest = hashlib.sha256(f"gcps-chunks/{DIGEST_CHUNK}|{stack.shape}|{stack.dtype.str}|".encode())
    for part in parts:
        digest.update(part)
    return digest.hexdigest()


DIGEST_CHUNK = 1 << 21
"""Bytes per chunk of :func:`stack_digest`'s hash list (2 MiB: a 1280x1024 gcps-v1 stack is 7 chunks)."""


def reference_key(model: GeometryModel, digest: str, codec: Codec | None, options: MeasureOptions) -> str:
    """The local cache key of the reference of the stack whose :func:`stack_digest` is ``digest``."""
    return _key(model, codec, options, {"stack_sha256": digest})


def _key(model: GeometryModel, codec: Codec | None, options: MeasureOptions, capture: Mapping[str, Any]) -> str:
    """The local cache key of a reference: what identifies its ``capture``, with the rig's model, the
    codec and the measurement options (and the software version: :func:`local_cache.entry_key`)."""
    return local_cache.entry_key(
        KIND,
        {
            **capture,
            "model": model.to_dict(),
            "codec": None if codec is None else codec.to_dict(),
            "options": options.to_dict(),
        },
    )


def reference_arrays(reference: Reference) -> dict[str, np.ndarray]:
    """The arrays that store ``reference`` (its model, codec and geometry options excepted): the
    codes, the packed unreliable mask, the surfaces' fields, and ``meta`` (a JSON header as uint8)."""
    arrays: dict[str, np.ndarray] = {}
    names: dict[int, str] = {}

    def array(name: str, value: np.ndarray) -> str:
        known = names.get(id(value))
        if known is not None:
            return known
        names[id(value)] = name
        arrays[name] = value
        return name

    meta: dict[str, Any] = {
        "codes": array("codes", reference.codes),
        "blur_variance_px2": reference.blur_variance_px2,
        "surface": _surface_meta(reference.surface, "surface", array),
        "gray_surface": None
        if reference.gray_surface is None
        else _surface_meta(reference.gray_surface, "gray_surface", array),
        "unreliable": None,
    }
    if reference.unreliable is not None:
        mask = np.asarray(reference.unreliable, dtype=bool)
        arrays["unreliable_bits"] = np.packbits(mask.reshape(-1))
        meta["unreliable"] = list(mask.shape)
    arrays[_META] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    return arrays


def _surface_meta(surface: ReferenceSurface, prefix: str, array: Any) -> dict[str, Any]:
    cls = type(surface)
    if not dataclasses.is_dataclass(surface) or not cls.__module__.startswith(_SURFACE_MODULES):
        raise TypeError(f"cannot store a reference surface of type {cls.__module__}.{cls.__qualname__}")
    fields: dict[str, Any] = {}
    for f in dataclasses.fields(surface):
        value = getattr(surface, f.name)
        if isinstance(value, np.ndarray):
            fields[f.name] = {"array": array(f"{prefix}.{f.name}", value)}
        elif isinstance(value, tuple):
            fields[f.name] = {"tuple": list(value)}
        else:
            fields[f.name] = {"value": value}
    return {"class": f"{cls.__module__}:{cls.__qualname__}", "fields": fields}


def reference_from_arrays(
    arrays: dict[str, np.ndarray], model: GeometryModel, codec: Codec | None, options: MeasureOptions
) -> Reference:
    """Inverse of :func:`reference_arrays`, for ``model``, ``codec`` and ``options`` (those of the key).

    Raises
    ------
    ValueError
        If the arrays do not hold a stored reference.
    """
    try:
        meta = json.loads(bytes(arrays[_META]))
        unreliable = None
        if meta["unreliable"] is not None:
            shape = tuple(int(n) for n in meta["unreliable"])
            bits = np.unpackbits(arrays["unreliable_bits"], count=int(np.prod(shape)))
            unreliable = bits.view(bool).reshape(shape)
        return Reference(
            model=model,
            codec=codec,
            geometry=options.geometry,
            surface=_surface_of(meta["surface"], arrays),
            codes=arrays[meta["codes"]],
            unreliable=unreliable,
            blur_variance_px2=float(meta["blur_variance_px2"]),
            gray_surface=None if meta["gray_surface"] is None else _surface_of(meta["gray_surface"], arrays),
        )
    except (KeyError, TypeError, ValueError, AttributeError, ImportError, json.JSONDecodeError) as exc:
        raise ValueError(f"not a stored reference: {exc}") from exc


def _surface_of(meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> ReferenceSurface:
    module_name, _, qualname = meta["class"].partition(":")
    if not module_name.startswith(_SURFACE_MODULES):
        raise ValueError(f"unexpected surface class {meta['class']}")
    cls = getattr(importlib.import_module(module_name), qualname)
    if not (isinstance(cls, type) and issubclass(cls, ReferenceSurface)):
        raise ValueError(f"{meta['class']} is not a reference surface")
    values: dict[str, Any] = {}
    for name, spec in meta["fields"].items():
        if "array" in spec:
            values[name] = arrays[spec["array"]]
        elif "tuple" in spec:
            values[name] = tuple(spec["tuple"])
        else:
            values[name] = spec["value"]
    surface: ReferenceSurface = cls(**values)
    return surface


def cached_reference(
    model: GeometryModel,
    images: npt.ArrayLike | ExposureStack | tuple[np.ndarray, ...],
    codec: Codec | None = None,
    options: MeasureOptions | None = None,
    *,
    threads: int | None = None,
) -> tuple[Reference, dict[str, Any]]:
    """:func:`~metrology.core.measure.prepare_reference`, through the local cache, keyed by the
    decoded frames (:func:`stack_digest`).

    Returns the reference and what happened: ``{"hit": bool, "key": "frames", "hash_s", "load_s"
    or "decode_s"}`` (seconds). A miss decodes, returns, and writes the entry on a background
    thread (:func:`metrology.core.local_cache.store_later`; the interpreter waits for it at exit).
    """
    options = options or MeasureOptions()
    stack: ExposureStack | np.ndarray | tuple[np.ndarray, ...]
    if isinstance(images, (tuple, list)):  # one stack per camera: results on camera 0's grid
        stack = tuple(np.asarray(frames) for frames in images)
    elif isinstance(images, ExposureStack):
        stack = images
    else:
        stack = np.asarray(images)
    start = time.perf_counter()
    key = reference_key(model, stack_digest(stack), codec, options)
    report: dict[str, Any] = {"key": "frames", "hash_s": time.perf_counter() - start}
    return _kept_or_prepared(key, model, lambda: stack, codec, options, threads, report, lambda: True)


def files_reference_key(
    model: GeometryModel, files_digest: str, reader: Mapping[str, Any], codec: Codec | None, options: MeasureOptions
) -> str:
    """The local cache key of the reference of the capture whose files' digest is ``files_digest``
    (:func:`~metrology.core.io.digests.capture_files_digest`), read by ``reader`` (the reader's
    options: a JSON-ready description of how the files become frames)."""
    return _key(model, codec, options, {"capture_files_sha256": files_digest, "reader": dict(reader)})


def cached_reference_of_files(
    model: GeometryModel,
    capture: str | os.PathLike[str],
    read: Callable[[], npt.ArrayLike | ExposureStack | tuple[np.ndarray, ...]],
    reader: Mapping[str, Any],
    codec: Codec | None = None,
    options: MeasureOptions | None = None,
    *,
    threads: int | None = None,
    digest: Callable[[], str] | None = None,
) -> tuple[Reference, dict[str, Any]]:
    """:func:`~metrology.core.measure.prepare_reference` of the capture at ``capture`` (a folder or a
    file), through the local cache, keyed by the capture's files
    (:func:`~metrology.core.io.digests.capture_files_digest`) and ``reader`` (what ``read()`` does
    with them) besides the rig, codec, options and version (:func:`files_reference_key`): a hit
    reads no image; a miss calls ``read()`` for the frames, decodes them and keeps the reference
    unless the files changed meanwhile (hashed again after the read). ``digest``: the capture's
    files digest computed beforehand (``gcps measure`` starts it with the command), called for it
    instead of hashing the files here; ``hash_s`` is then the time waited for it.

    Returns the reference and what happened: ``{"hit": bool, "key": "files", "hash_s", "load_s",
    or "read_s" and "decode_s"}`` (seconds).

    Raises
    ------
    OSError
        If the capture's files cannot be read (``read()``'s own errors pass through).
    """
    options = options or MeasureOptions()
    start = time.perf_counter()
    files = capture_files_digest(capture, threads) if digest is None else digest()
    key = files_reference_key(model, files, reader, codec, options)
    report: dict[str, Any] = {"key": "files", "hash_s": time.perf_counter() - start}

    def frames() -> npt.ArrayLike | ExposureStack | tuple[np.ndarray, ...]:
        start = time.perf_counter()
        images = read()
        report["read_s"] = time.perf_counter() - start
        return images

    def unchanged() -> bool:
        return capture_files_digest(capture, threads) == files

    return _kept_or_prepared(key, model, frames, codec, options, threads, report, unchanged)


def _kept_or_prepared(
    key: str,
    model: GeometryModel,
    frames: Callable[[], npt.ArrayLike | ExposureStack | tuple[np.ndarray, ...]],
    codec: Codec | None,
    options: MeasureOptions,
    threads: int | None,
    report: dict[str, Any],
    keep: Callable[[], bool],
) -> tuple[Reference, dict[str, Any]]:
    """The reference stored under ``key`` when it is there and fits the model's camera 0; else the
    reference prepared from ``frames()``, stored under ``key`` when ``keep()``. ``report`` gets
    ``hit`` and ``load_s`` or ``decode_s``."""
    start = time.perf_counter()
    arrays = local_cache.load(KIND, key)
    if arrays is not None:
        try:
            reference = reference_from_arrays(arrays, model, codec, options)
        except ValueError:
            reference = None
        if reference is not None and tuple(reference.shape) == tuple(model.camera_shapes[0]):
            report.update(hit=True, load_s=time.perf_counter() - start)
            return reference, report
    images = frames()
    start = time.perf_counter()
    reference = prepare_reference(model, images, codec, options, threads=threads)
    report.update(hit=False, decode_s=time.perf_counter() - start)
    # without gray-code-only heights (in the key) the gray surface is never read: not stored (half the entry)
    kept = reference if options.gray_only else dataclasses.replace(reference, gray_surface=None)
    try:
        stored = reference_arrays(kept)
    except TypeError:  # a surface this module cannot store: measured, not kept
        return reference, report
    if keep():
        local_cache.store_later(KIND, key, stored)
    return reference, report


__all__ = [
    "KIND",
    "cached_reference",
    "cached_reference_of_files",
    "files_reference_key",
    "reference_arrays",
    "reference_from_arrays",
    "reference_key",
    "stack_digest",
]
