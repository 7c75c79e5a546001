"""The kept reference of a capture in this process: decoded once, reused by every job that measures against it.

Keyed by the capture's id and sha256, the rig values and the decoding options, so a changed rig
or option decodes again and a replaced file is never mistaken for the one decoded. Bounded by
``GCPS_REFERENCE_CACHE_BYTES`` per process (least recently used evicted first).
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

from django.conf import settings

from metrology.captures.models import Capture
from metrology.pipeline.kept_references import KeptReferences

if TYPE_CHECKING:  # pragma: no cover
    from metrology.core.codecs.model import Codec
    from metrology.core.measure import MeasureOptions, Reference

_kept: KeptReferences | None = None


def kept_references() -> KeptReferences:
    """This process's kept references (rebuilt empty if ``GCPS_REFERENCE_CACHE_BYTES`` changed)."""
    global _kept
    limit = settings.GCPS_REFERENCE_CACHE_BYTES
    if _kept is None or _kept.max_bytes != limit:
        _kept = KeptReferences(limit)
    return _kept


def reference_key(
    capture: Capture, rig_values: dict[str, Any], codec: Codec | None, options: MeasureOptions, exposures: bool = False
) -> tuple[Any, ...]:
    """What identifies a decoded reference: capture id and sha256, rig values, codec, the
    decoding, filter and triangulation options, and whether it was decoded as (or as one exposure
    of) a multi-exposure capture."""
    settings_of = {key: value for key, value in options.to_dict().items() if key in ("decode", "triangulate", "method")}
    return (
        capture.pk,
        capture.checksum_sha256,
        capture.file.name,
        json.dumps(rig_values, sort_keys=True),
        None if codec is None else json.dumps(codec.to_dict(), sort_keys=True),
        json.dumps(settings_of, sort_keys=True),
        exposures,
    )


def kept_reference(
    capture: Capture,
    rig_values: dict[str, Any],
    codec: Codec | None,
    options: MeasureOptions,
    *,
    exposures: bool = False,
) -> tuple[Reference, bool]:
    """The reference plane of ``capture`` prepared for the rig ``rig_values`` (any model) and its
    ``codec``; and whether it was kept (no decode). ``exposures``: the measurement involves a
    multi-exposure capture, so the reference is decoded as one too (a single stack as its only
    exposure: :func:`metrology.core.measure.exposure_inputs`, docs/exposures.md)."""
    from metrology.captures.stacks import load_capture_images
    from metrology.core.geometry import model_from_dict
    from metrology.core.measure import as_exposures
    from metrology.pipeline.measure import prepare_reference

    def prepare() -> Reference:
        images = load_capture_images(capture)
        if exposures:  # a single stack as its only exposure, per camera
            images = as_exposures(images)
        return prepare_reference(model_from_dict(rig_values), images, options, codec=codec)

    return kept_references().get(reference_key(capture, rig_values, codec, options, exposures), prepare)
