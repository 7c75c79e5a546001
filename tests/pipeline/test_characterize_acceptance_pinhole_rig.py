"""The pipeline's one characterize and acceptance (and `gcps characterize` / `gcps acceptance`)
with a pinhole rig (issue 12), on the pinhole virtual rig: a stage series of a plane moved along
the reference plane's normal.

The virtual rig's scenes face the camera (:meth:`ScenePlacement.facing_camera`: reference plane ``Z = 600`` mm),
so the reference plane's normal is the camera's Z axis and a plane scene at height ``z_mm``
sits at ``Z = 600 - z_mm``: the stage moves along that normal, the direction in which the
heights (distances to the reference plane) are measured, so the true in-out slope is 1.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from metrology.cli import main
from metrology.core.codecs import codec_from_dict, render_codec
from metrology.core.scenes import make_scene
from metrology.core.simulate import SimulationOptions
from metrology.pipeline.acceptance import AcceptanceOptions, acceptance
from metrology.pipeline.characterize import CharacterizeOptions, characterize
from metrology.pipeline.measure import MeasureOptions, measure
from tests.pinhole_stacks import CODEC, RIG, cast_scene

DISTANCE_MM = 600.0
STAGE_MM = (0.0, 4.0, 8.0, 12.0, 16.0)


def _plane(z_mm: float, options: SimulationOptions | None = None, seed: int | None = None) -> np.ndarray:
    """Frames of the codec of a plane ``z_mm`` above the reference plane; with ``options``, rendered
    from ``options.supersample`` rays per pixel and axis."""
    supersample = 1 if options is None else options.supersample
    truth = cast_scene("plane", DISTANCE_MM, supersample=supersample, z_mm=z_mm)
    return render_codec(codec_from_dict(CODEC), truth.u, None, options, seed=seed)


def test_noise_free_stage_series_slopes_one_errors_under_one_micron() -> None:
    codec = codec_from_dict(CODEC)
    reference = _plane(0.0)
    series = [(z, 0, _plane(z)) for z in STAGE_MM]
    result = characterize(RIG, reference, series, CharacterizeOptions(n_points=9, rows=3), codec=codec)
    report = result.report
    assert report["model"] == "pinhole" and report["z_in_mm"] == list(STAGE_MM)
    points = report["test_points"]
    assert len(points) == 27 and all(p["n_positions"] == len(STAGE_MM) for p in points)
    slopes = np.array([p["slope"] for p in points])
    assert np.abs(slopes - 1).max() < 1e-5, slopes
    assert report["overall"]["max_abs_slope_deviation"] < 1e-5
    assert max(abs(e) for e in report["mean_error_mm"]) < 1e-3
    assert abs(report["overall"]["mean_error_mm"]) < 1e-3 and report["overall"]["std_error_mm"] < 1e-3
    # test points: camera-frame X, Y of the reference plane (Z = 600) seen by the patch centre
    truth = cast_scene("plane", DISTANCE_MM, z_mm=0.0).points_mm
    for p in points:
        assert p["x_mm"] == pytest.approx(truth[p["row_px"], p["column_px"], 0], abs=1e-3)
        assert p["y_mm"] == pytest.approx(truth[p["row_px"], p["column_px"], 1], abs=1e-3)
    # test points sit along camera columns of the chosen rows, left to right
    assert [p["column_px"] for p in points[:9]] == sorted(p["column_px"] for p in points[:9])
    assert len({p["row_px"] for p in points}) == 3


def test_noise_free_flatness_and_probing_in_camera_frame() -> None:
    codec = codec_from_dict(CODEC)
    flat = acceptance(RIG, None, _plane(5.0), AcceptanceOptions(test="flatness"), codec=codec).to_dict()
    assert flat["model"] == "pinhole" and flat["frame"] == "camera"
    assert flat["flatness_mm"] < 2e-3, flat
    sphere = cast_scene("sphere", DISTANCE_MM)
    diameter = 2 * make_scene("sphere").radius_mm  # type: ignore[attr-defined]
    probe = acceptance(
        RIG,
        _plane(0.0),
        render_codec(codec, sphere.u, None),
        AcceptanceOptions(test="probing", diameter_mm=diameter),
        codec=codec,
    ).to_dict()
    assert abs(probe["size_error_mm"]) < 1e-3 and probe["form_error_mm"] < 5e-3, probe
    with pytest.raises(ValueError, match="give a reference capture"):
        acceptance(RIG, None, _plane(5.0), AcceptanceOptions(test="probing", diameter_mm=diameter), codec=codec)


@pytest.mark.slow
def test_realistic_flatness_consistent_with_noise() -> None:
    """8-bit realistic renders: the RMS of the plane's TLS residuals matches the points' predicted
    uncertainty (median per-point sigma along the rays, from the decoder's noise) within 25 %, and
    its flatness error (range of the residuals over N ~ 10^4 points, about 7-8 sigma for Gaussian
    noise) lies between 4 and 12 times that RMS; the stage series' slopes stay near 1."""
    codec = codec_from_dict(CODEC)
    # camera defocus off: the renderer's replicated-border blur biases the first and last columns
    # by ~0.8 mm (a renderer edge effect, not noise); 8-bit, grey noise, ambient, projector blur stay
    options = SimulationOptions.realistic_8bit(camera_defocus_px=0.0)
    plane = _plane(5.0, options, seed=1)
    flat = acceptance(RIG, None, plane, AcceptanceOptions(test="flatness"), codec=codec)
    report = flat.report
    predicted = measure(RIG, None, plane, MeasureOptions(sigma=True), codec=codec).statistics()
    rms = report["rms_mm"]
    assert rms == pytest.approx(predicted["sigma_mm_median"], rel=0.25), (report, predicted)
    assert 4 * rms < report["flatness_mm"] < 12 * rms, report
    reference = _plane(0.0, options, seed=2)
    series = [(z, r, _plane(z, options, seed=10 + 3 * i + r)) for i, z in enumerate(STAGE_MM) for r in range(2)]
    result = characterize(RIG, reference, series, CharacterizeOptions(n_points=9), codec=codec)
    overall = result.report["overall"]
    assert overall["max_abs_slope_deviation"] < 2e-3, overall
    assert abs(overall["mean_error_mm"]) < 0.05 and overall["std_error_mm"] < 0.05, overall


def _write_capture(folder: Path, images: np.ndarray) -> None:
    folder.mkdir(parents=True)
    for i, image in enumerate(images):
        cv2.imwrite(str(folder / f"frame_{i:02d}.png"), image)
    (folder / "codec.json").write_text(json.dumps(CODEC))


def test_cli_characterize_and_acceptance_with_pinhole_rig(tmp_path: Path) -> None:
    """`gcps characterize` / `gcps acceptance --rig PINHOLE.json`: the captures' codec.json (or
    --codec), the same figures as the pipeline; bad input exits 2."""
    (tmp_path / "rig.json").write_text(RIG.to_json())
    _write_capture(tmp_path / "ref", _plane(0.0))
    positions = []
    for z in STAGE_MM[:3]:
        _write_capture(tmp_path / f"z{z:03.0f}", _plane(z))
        positions.append({"z_in_mm": z, "captures": [f"z{z:03.0f}"]})
    (tmp_path / "series.json").write_text(json.dumps({"positions": positions}))
    (tmp_path / "codec.json").write_text(json.dumps(CODEC))
    common = ["--quiet", "characterize", "--rig", str(tmp_path / "rig.json"), "--reference", str(tmp_path / "ref")]
    args = [*common, "--series", str(tmp_path / "series.json"), "--points", "5", "--out", str(tmp_path / "c.json")]
    assert main([*args, "--codec", str(tmp_path / "codec.json")]) == 0
    report = json.loads((tmp_path / "c.json").read_text())
    assert report["model"] == "pinhole" and report["z_in_mm"] == [0.0, 4.0, 8.0]
    assert report["overall"]["max_abs_slope_deviation"] < 1e-5 and abs(report["overall"]["mean_error_mm"]) < 1e-3
    assert report["codec"]["codec"] == "gcps-codec/1" and report["rig"]["model"] == "pinhole"
    flat = ["--quiet", "acceptance", "--rig", str(tmp_path / "rig.json"), "--object", str(tmp_path / "z008")]
    assert main([*flat, "--test", "flatness", "--out", str(tmp_path / "f.json")]) == 0
    result = json.loads((tmp_path / "f.json").read_text())
    assert result["standard"] == "VDI/VDE 2634 part 2" and result["flatness_mm"] < 2e-3
    # probing without a reference: exit 2, nothing written
    assert main([*flat, "--test", "probing", "--diameter", "100", "--out", str(tmp_path / "p.json")]) == 2
    assert not (tmp_path / "p.json").exists()


def test_cli_crossed_axes_rig_keeps_needing_a_reference_and_takes_a_codec(tmp_path: Path, capsys) -> None:
    """A crossed-axes rig still needs --reference (exit 2, nothing written). --codec, once refused
    on a crossed-axes rig, now names the captures' codec for every model (issue 20: one path for
    every codec and model): gcps-v1 captures of the paper's rig measured with --codec gcps-v1."""
    from metrology.core.io import write_rig, write_stack
    from tests.app.stacks import render_images
    from tests.commands.rigs import RIG as CROSSED

    write_rig(CROSSED, tmp_path / "rig.json")
    base = ["--quiet", "acceptance", "--rig", str(tmp_path / "rig.json"), "--object", str(tmp_path / "obj")]
    assert main([*base, "--test", "flatness", "--out", str(tmp_path / "f.json")]) == 2
    err = capsys.readouterr().err
    assert "--reference is required: a crossed-axes rig measures against a capture of the reference plane" in err
    assert not (tmp_path / "f.json").exists()
    write_stack(render_images(CROSSED, 0.0, bit_depth=16), tmp_path / "ref")
    write_stack(render_images(CROSSED, 10.0, bit_depth=16), tmp_path / "obj")
    with_ref = [*base, "--reference", str(tmp_path / "ref"), "--test", "flatness", "--out", str(tmp_path / "f.json")]
    assert main([*with_ref, "--codec", "gcps-v1"]) == 0
    result = json.loads((tmp_path / "f.json").read_text())
    assert result["model"] == "crossed_axes" and result["codec"]["codec"] == "gcps-codec/1"
    assert result["flatness_mm"] < 2e-3, result
