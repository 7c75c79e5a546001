"""Measurements of captures of a codec other than gcps-v1 (docs/codecs.md): the codec both captures
share, and the job handler's branch that decodes them with the codec decoder.

gcps-v1 measurements keep the handler of :mod:`metrology.measurements.services` unchanged; a
measurement whose captures have another codec (coding the projector's u axis) is computed here
by the same pipeline function, :func:`metrology.pipeline.measure`, with ``codec=``, against a
reference kept per worker, and stored the same way (the height map and statistics; TIFF and
meshes derived on request), the statistics holding the codec and the decoding summary (pixels
per reason, repaired slips, the validity rules used).
"""

from __future__ import annotations

import json
import time
from typing import Any

import numpy as np

from metrology.captures.codecs import capture_codec_value, codec_of, is_gcps_v1
from metrology.errors import BadInput
from metrology.jobs import services as job_services
from metrology.jobs.models import Job
from metrology.measurements.models import Measurement
from metrology.measurements.stored_arrays import save_arrays, sigma_statistics
from metrology.pipeline.jsonsafe import json_safe


def stacks_codec_value(reference: Any, obj: Any) -> Any:
    """The stored codec value both captures share (each its own, else its rig's default).

    Raises
    ------
    BadInput
        When they differ, or when the codec does not code the projector's u axis.
    """
    ref_value, obj_value = capture_codec_value(reference), capture_codec_value(obj)
    ref_codec, obj_codec = codec_of(ref_value), codec_of(obj_value)
    if ref_codec != obj_codec or ref_codec.name != obj_codec.name:
        raise BadInput(
            f"object: capture {obj.pk} has another codec than the reference capture {reference.pk} "
            "(both captures of a measurement must use one codec)"
        )
    if "u" not in obj_codec.axes:
        raise BadInput(f"object: the codec of capture {obj.pk} does not code the projector's u axis")
    return obj_value


def job_codec(job: Job) -> Any:
    """The :class:`~metrology.core.codecs.model.Codec` of a measurement job when it is not gcps-v1, else None."""
    value = job.parameters.get("codec")
    if value is None:
        return None
    codec = codec_of(value)
    return None if is_gcps_v1(codec) else codec


def kept_codec_reference(capture: Any, rig_values: dict[str, Any], decode: Any, codec: Any) -> tuple[Any, bool]:
    """The decoded reference plane of a capture of ``codec`` (a
    :class:`~metrology.core.codec_measure.CodecReference`), kept per worker like the gcps-v1 ones
    (:mod:`metrology.captures.references`); and whether it was kept (no decode)."""
    from metrology.captures.codecs import load_codec_stack
    from metrology.captures.references import kept_references, reference_key
    from metrology.core.codec_measure import prepare_codec_reference
    from metrology.core.rig import Rig as CoreRig

    def prepare() -> Any:
        return prepare_codec_reference(CoreRig.from_dict(rig_values), load_codec_stack(capture).images, codec, decode)

    key = (*reference_key(capture, rig_values, decode), json.dumps(codec.to_dict(), sort_keys=True))
    return kept_references().get(key, prepare)


def run_codec_measurement(job: Job, run: job_services.JobRun, codec: Any) -> None:
    """Job handler for captures of ``codec``: the kept reference, the object's stack in codec order, the
    pipeline's measure; store the height map and publish, as the gcps-v1 handler does (the TIFF and
    the meshes are derived on request)."""
    from metrology.captures.codecs import load_codec_stack
    from metrology.core.rig import Rig as CoreRig
    from metrology.measurements.services import _remove_other_attempts
    from metrology.pipeline import MeasureOptions, measure

    measurement = Measurement.objects.select_related("reference__rig", "object__rig").get(job=job)
    rig = CoreRig.from_dict(measurement.rig_values)
    options = MeasureOptions.from_dict(measurement.options or {})
    with run.phase("reference", 5):
        reference, _kept = kept_codec_reference(measurement.reference, measurement.rig_values, options.decode, codec)
    with run.phase("read", 10):
        obj = load_codec_stack(measurement.object)
    with run.phase("measure", 20):
        result = measure(rig, reference, obj.images, options, codec=codec)
    for name, seconds in result.timings_s.items():
        if name != "measure":
            run.timings[name] = round(float(seconds), 4)
    z_mm = np.asarray(result.z_mm, dtype=np.float32)
    prefix = f"measurements/{measurement.pk}/{run.token.hex}"
    arrays = {"height.npy": z_mm}
    if result.sigma_mm is not None:  # options.sigma
        arrays["sigma.npy"] = np.asarray(result.sigma_mm, dtype=np.float32)
    with run.phase("store", 80):
        names = save_arrays(run, prefix, arrays)
    statistics = json_safe(result.statistics())
    statistics["shape"] = list(z_mm.shape)
    statistics.update(sigma_statistics(result.sigma_mm))
    statistics["codec"] = json.loads(json.dumps(job.parameters.get("codec")))
    if result.decoding is not None:
        statistics["decoding"] = json_safe(result.decoding.summary())

    def publish(job_row: Job) -> None:
        start = time.perf_counter()
        Measurement.objects.filter(pk=measurement.pk).update(
            height_npy=names["height.npy"],
            gray_only_npy="",
            sigma_npy=names.get("sigma.npy", ""),
            statistics=statistics,
            options=result.options.to_dict(),
        )
        job_row.software_version = result.software_version
        run.timings["publish"] = round(time.perf_counter() - start, 4)

    run.commit(publish)
    _remove_other_attempts(prefix)
