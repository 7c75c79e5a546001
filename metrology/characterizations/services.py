"""Writes for characterizations: request (a queued job) and compute the paper's section 5 figures."""

from __future__ import annotations

import csv
import io
import math
from collections import defaultdict
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from django.db import transaction

from metrology.captures.codecs import captures_codec_value, codec_of
from metrology.captures.models import Capture, CaptureSession
from metrology.captures.selectors import capture_for_job
from metrology.captures.stacks import load_capture_images
from metrology.characterizations.models import Characterization
from metrology.errors import BadInput
from metrology.jobs import services as job_services
from metrology.jobs.models import Job
from metrology.pipeline.jsonsafe import json_safe
from metrology.rigs.models import Rig

OPTION_TYPES: dict[str, type] = {"n_points": int, "rows": int, "patch_px": int, "margin_frac": float}


def _check_options(options: dict[str, Any]) -> dict[str, Any]:
    unknown = sorted(set(options) - set(OPTION_TYPES))
    if unknown:
        raise BadInput(f"options: unknown option(s) {', '.join(unknown)}; accepted: {', '.join(OPTION_TYPES)}")
    for name, value in options.items():
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise BadInput(f"options.{name} must be a number, got {value!r}")
        if OPTION_TYPES[name] is int and not float(value).is_integer():
            raise BadInput(f"options.{name} must be an integer, got {value!r}")
    if "patch_px" in options and (options["patch_px"] < 1 or options["patch_px"] % 2 == 0):
        raise BadInput(f"options.patch_px must be an odd positive integer, got {options['patch_px']}")
    if "n_points" in options and not 1 <= options["n_points"] <= 1000:
        raise BadInput(f"options.n_points must lie in [1, 1000], got {options['n_points']}")
    if "margin_frac" in options and not 0 <= options["margin_frac"] < 0.5:
        raise BadInput(f"options.margin_frac must lie in [0, 0.5), got {options['margin_frac']}")
    return {name: OPTION_TYPES[name](value) for name, value in options.items()}


def _series_from_session(owner, rig: Rig, session_id: int) -> list[dict[str, Any]]:
    session = CaptureSession.objects.filter(pk=session_id, owner=owner).first()
    if session is None:
        raise BadInput(f"session: session {session_id} does not exist among yours")
    if session.rig_id != rig.pk:
        raise BadInput(f"session: session {session_id} belongs to rig {session.rig_id}, not to rig {rig.pk}")
    positions: dict[float, list[int]] = defaultdict(list)
    for capture in session.captures.filter(role=Capture.Role.STAGE).order_by("z_in_mm", "repeat", "id"):
        assert capture.z_in_mm is not None, "stage captures carry their position (captures.services._check_stage)"
        positions[capture.z_in_mm].append(capture.pk)
    return [{"z_in_mm": z, "captures": ids} for z, ids in sorted(positions.items())]


@transaction.atomic
def request_characterization(
    *,
    owner,
    rig: Rig,
    reference_id: int,
    series: list[dict[str, Any]] | None = None,
    session_id: int | None = None,
    options: dict[str, Any] | None = None,
) -> Characterization:
    """Create a characterization from a stage series (explicit, or a session's stage captures) and queue it.

    Any model and codec (the reference's; every stage capture must share it): each stage capture's
    heights above the reference plane (:func:`metrology.pipeline.characterize.characterize`).
    """
    if (series is None) == (session_id is None):
        raise BadInput("give either series (stage positions with capture ids) or session (a capture session)")
    if session_id is not None:
        series = _series_from_session(owner, rig, session_id)
    options = _check_options(dict(options or {}))
    used = _pipeline_options(options).to_dict()
    reference = capture_for_job(owner, rig, reference_id, field="reference", roles=(Capture.Role.REFERENCE,))
    model = rig.to_core()
    codec = captures_codec_value(model, None, reference, what="reference")
    checked: list[dict[str, Any]] = []
    seen: set[int] = set()
    for index, position in enumerate(series or []):
        z_in = position["z_in_mm"]
        if not math.isfinite(z_in):
            raise BadInput(f"series[{index}].z_in_mm must be a finite number, got {z_in}")
        ids = list(position["captures"])
        if not ids:
            raise BadInput(f"series[{index}] (z_in_mm = {z_in}) lists no capture")
        for capture_id in ids:
            if capture_id in seen:
                raise BadInput(f"series[{index}]: capture {capture_id} is listed twice")
            seen.add(capture_id)
            stage = capture_for_job(owner, rig, capture_id, field=f"series[{index}]", roles=(Capture.Role.STAGE,))
            captures_codec_value(model, reference, stage, what=f"series[{index}]")
        checked.append({"z_in_mm": float(z_in), "captures": ids})
    if len({position["z_in_mm"] for position in checked}) < 2:
        raise BadInput("a characterization needs stage captures at two or more distinct z_in_mm positions")
    parameters: dict[str, Any] = {
        "rig": rig.pk,
        "reference": reference.pk,
        "series": checked,
        "options": options,
        "codec": codec,
    }
    rig_values = rig.rig_file()
    job = job_services.create_job(owner=owner, kind=Job.Kind.CHARACTERIZATION, parameters=parameters)
    characterization = Characterization.objects.create(
        owner=owner,
        rig=rig,
        reference=reference,
        session_id=session_id,
        series=checked,
        parameters={"options": options},
        rig_values=rig_values,
        options=used,
        job=job,
    )
    job.parameters["characterization"] = characterization.pk
    job.save(update_fields=["parameters"])
    job_services.enqueue_job(job)
    return characterization


def _pipeline_options(options: dict[str, Any]) -> Any:
    """:class:`metrology.pipeline.CharacterizeOptions` of a request's options (BadInput naming a bad value)."""
    from metrology.pipeline.characterize import CharacterizeOptions

    try:
        return CharacterizeOptions(**options)
    except (TypeError, ValueError) as exc:
        raise BadInput(f"options: {exc}") from exc


def run_characterization(job: Job, run: job_services.JobRun) -> None:
    """Job handler: the kept reference, the stage stacks (each read while the previous one is measured),
    the pipeline's characterize (section 5's figures), publish."""
    from metrology.captures.references import kept_reference
    from metrology.core.geometry import model_from_dict
    from metrology.core.measure import MeasureOptions
    from metrology.pipeline.characterize import CharacterizeOptions, characterize

    characterization = Characterization.objects.select_related("reference__rig").get(job=job)
    model = model_from_dict(characterization.rig_values)
    if characterization.options:
        options = CharacterizeOptions.from_dict(characterization.options)
    else:  # requested before options were stored
        options = _pipeline_options(dict(characterization.parameters.get("options") or {}))
    codec_value = job.parameters.get("codec")
    codec = None if codec_value is None else codec_of(codec_value)
    items = [
        (p["z_in_mm"], r, capture_id) for p in characterization.series for r, capture_id in enumerate(p["captures"])
    ]
    with run.phase("reference", 2):
        reference, _kept = kept_reference(
            characterization.reference, characterization.rig_values, codec, MeasureOptions.of(options)
        )
    captures = Capture.objects.select_related("rig").in_bulk([capture_id for _z, _r, capture_id in items])

    def stacks() -> Any:
        # the next stack is read (inflated and decoded, GIL released) while this one is measured
        with ThreadPoolExecutor(max_workers=1) as reader:
            pending = [reader.submit(load_capture_images, captures[capture_id]) for _z, _r, capture_id in items[:1]]
            for done, (z_in, repeat, _capture_id) in enumerate(items):
                run.progress(5 + int(85 * done / len(items)), f"stage {done + 1}/{len(items)}")
                images = pending.pop().result()
                if done + 1 < len(items):
                    pending.append(reader.submit(load_capture_images, captures[items[done + 1][2]]))
                yield z_in, repeat, images

    with run.phase("characterize", 5):
        outcome = characterize(model, reference, stacks(), options, codec=codec)
    _publish(run, characterization, outcome)


def _publish(run: job_services.JobRun, characterization: Characterization, outcome: Any) -> None:
    """Store a characterization's results, options and overall figures; commit the job."""
    for name, seconds in outcome.timings_s.items():
        run.timings[f"characterize.{name}"] = round(float(seconds), 4)
    results = json_safe(outcome.report)
    overall = results.get("overall", {})

    def publish(job_row: Job) -> None:
        Characterization.objects.filter(pk=characterization.pk).update(
            results=results,
            options=outcome.options.to_dict(),
            overall_mean_error_mm=overall.get("mean_error_mm"),
            overall_std_error_mm=overall.get("std_error_mm"),
        )
        job_row.software_version = outcome.software_version  # the code that computed it

    run.commit(publish)


def positions_csv(characterization: Characterization) -> str:
    """Per stage position: z_in_mm, mean_error_mm, std_error_mm, n_samples (paper Fig. 13)."""
    results = characterization.results or {}
    out = io.StringIO()
    writer = csv.writer(out)
    writer.writerow(["z_in_mm", "mean_error_mm", "std_error_mm", "n_samples"])
    columns = [results.get(key, []) for key in ("z_in_mm", "mean_error_mm", "std_error_mm", "n_samples")]
    for row in zip(*columns, strict=False):
        writer.writerow(["" if value is None else value for value in row])
    return out.getvalue()


TEST_POINT_COLUMNS = (
    "x_mm",
    "y_mm",
    "row_px",
    "column_px",
    "slope",
    "intercept_mm",
    "r2",
    "sigma_mm",
    "mean_error_mm",
    "n_positions",
)


def test_points_csv(characterization: Characterization) -> str:
    """Per test point: position, in-out slope and intercept, r2, repeatability (paper Fig. 12)."""
    out = io.StringIO()
    writer = csv.writer(out)
    writer.writerow(TEST_POINT_COLUMNS)
    for point in (characterization.results or {}).get("test_points", []):
        writer.writerow(["" if point.get(key) is None else point.get(key) for key in TEST_POINT_COLUMNS])
    return out.getvalue()
