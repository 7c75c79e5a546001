"""The kept reference of a capture in this process: decoded once, reused by every job that measures against it.

Keyed by the capture's id and sha256, the rig values and the decoding options, so a changed rig
or option decodes again and a replaced file is never mistaken for the one decoded. Bounded by
``GCPS_REFERENCE_CACHE_BYTES`` per process (least recently used evicted first).
"""

from __future__ import annotations

import json
from typing import Any

from django.conf import settings

from metrology.captures.models import Capture
from metrology.captures.services import load_capture_stack
from metrology.core.measure import DecodeOptions, Reference, prepare_reference
from metrology.pipeline.kept_references import KeptReferences

_kept: KeptReferences | None = None


def kept_references() -> KeptReferences:
    """This process's kept references (rebuilt empty if ``GCPS_REFERENCE_CACHE_BYTES`` changed)."""
    global _kept
    limit = settings.GCPS_REFERENCE_CACHE_BYTES
    if _kept is None or _kept.max_bytes != limit:
        _kept = KeptReferences(limit)
    return _kept


def reference_key(capture: Capture, rig_values: dict[str, Any], decode: DecodeOptions) -> tuple[Any, ...]:
    """What identifies a decoded reference: capture id and sha256, rig values, decoding options."""
    return (
        capture.pk,
        capture.checksum_sha256,
        capture.file.name,
        json.dumps(rig_values, sort_keys=True),
        json.dumps(decode.to_dict(), sort_keys=True),
    )


def kept_reference(capture: Capture, rig_values: dict[str, Any], decode: DecodeOptions) -> tuple[Reference, bool]:
    """The decoded reference plane of ``capture`` for the rig ``rig_values``; and whether it was kept (no decode)."""
    from metrology.core.rig import Rig as CoreRig

    def prepare() -> Reference:
        return prepare_reference(CoreRig.from_dict(rig_values), load_capture_stack(capture).images, decode)

    return kept_references().get(reference_key(capture, rig_values, decode), prepare)
