"""gcps measure / the pipeline's measure with stacks of any codec coding u, on the crossed-axes rig.

The scenes are rendered twice by the virtual rig: as gcps-v1 (``render_stack``) and as a
12-step sine + gray code with inverse frames (``render_codec`` from ``crossed_rig_truth``,
the same true light codes), and both are measured against their own reference capture.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

from metrology.core.codecs import Codec, builtin_codec, codec_from_dict, render_codec
from metrology.core.decode import GcpsV1Options
from metrology.core.geometry.crossed_axes import PAPER_RIG as RIG
from metrology.core.geometry.crossed_axes import Rig
from metrology.core.scenes import make_scene
from metrology.core.simulate import SimulationOptions, crossed_rig_truth, render_stack
from metrology.pipeline.measure import MeasureOptions, measure

PROJ_W, PROJ_H = 1024, 768


def twelve_step_codec(period: float = 32.0) -> Codec:
    """u: 12-step sine of ``period`` px + a 5-bit gray code of period-wide words with inverses; white, black."""
    return codec_from_dict(
        {
            "codec": "gcps-codec/1",
            "frames": 24,
            "projector": {"width": PROJ_W, "height": PROJ_H},
            "white": [22],
            "black": [23],
            "axes": {
                "u": {
                    "phase": [{"frames": list(range(12)), "period": period, "origin": -0.5}],
                    "gray": {
                        "frames": list(range(12, 17)),
                        "word": period,
                        "origin": -0.5,
                        "inverse_frames": list(range(17, 22)),
                    },
                }
            },
        }
    )


CODEC = twelve_step_codec()


def render_both(scene_name: str, options: SimulationOptions, **params: Any) -> tuple[Any, np.ndarray]:
    """The gcps-v1 render of a scene and the codec's render of the same true projector columns."""
    rendered = render_stack(RIG, make_scene(scene_name, **params), options)
    u, _ = crossed_rig_truth(rendered, RIG, PROJ_W, PROJ_H)
    return rendered, render_codec(CODEC, u, None, options)


@pytest.fixture(scope="module")
def noise_free_reference() -> tuple[Any, np.ndarray]:
    return render_both("reference", SimulationOptions.noise_free_16bit())


@pytest.mark.parametrize(("scene", "params"), [("plane", {"z_mm": 30.0}), ("sphere", {}), ("staircase", {})])
def test_noise_free_codec_heights_within_1um_like_gcps_v1(scene, params, noise_free_reference):
    ref_v1, ref_codec = noise_free_reference
    rendered, images = render_both(scene, SimulationOptions.noise_free_16bit(), **params)
    v1 = measure(RIG, ref_v1.images, rendered.images, MeasureOptions(gray_only=False))
    coded = measure(RIG, ref_codec, images, MeasureOptions(gray_only=False), codec=CODEC)
    assert coded.codec_name == "gcps-codec/1" and coded.decoding is not None and v1.codec_name == "gcps-v1"
    for result in (v1, coded):
        error = result.z_mm - rendered.truth_mm
        valid = np.isfinite(error)
        # noise-free 16-bit: heights within 1 um of the analytic truth on every reported pixel
        assert np.abs(error[valid]).max() < 1e-3
    # the codec reports as many pixels as gcps-v1 (same filters; within 0.5 %)
    n_v1, n_codec = np.isfinite(v1.z_mm).sum(), np.isfinite(coded.z_mm).sum()
    assert n_codec >= 0.995 * n_v1 and n_v1 > 0.8 * rendered.lit.sum()
    data = coded.to_dict()
    assert data["codec"] == "gcps-codec/1" and data["decoding"]["axes"]["u"]["decoded"] > 0


@pytest.mark.slow
def test_realistic_twelve_steps_are_quieter_than_gcps_v1():
    """8-bit, 1.5 grey levels of noise, camera and projector blur (one ray per pixel: the codec
    renderer needs the true coordinates of every sub-ray): 12 steps at the same period as gcps-v1's
    4 steps have sqrt(3) less phase noise, so a plane's height scatter is lower, with no outlier."""
    opts = SimulationOptions.realistic_8bit(supersample=1)
    ref_v1, ref_codec = render_both("reference", opts.with_changes(seed=1))
    rendered, images = render_both("plane", opts.with_changes(seed=2), z_mm=30.0)
    v1 = measure(RIG, ref_v1.images, rendered.images, MeasureOptions(gray_only=False))
    coded = measure(RIG, ref_codec, images, MeasureOptions(gray_only=False), codec=CODEC)
    rms = {}
    for name, result in (("v1", v1), ("codec", coded)):
        error = result.z_mm - rendered.truth_mm
        valid = np.isfinite(error)
        assert valid.sum() > 0.9 * rendered.lit.sum()
        rms[name] = float(np.sqrt(np.mean(error[valid] ** 2)))
        if name == "codec":
            assert np.abs(error[valid]).max() < 0.5  # no pixel off by a period
    assert rms["codec"] < 0.8 * rms["v1"], rms


def test_gcps_v1_codec_takes_todays_path_bit_identically(noise_free_reference):
    ref_v1, _ = noise_free_reference
    rendered = render_stack(RIG, make_scene("sphere"), SimulationOptions.noise_free_16bit())
    today = measure(RIG, ref_v1.images, rendered.images)
    named = measure(RIG, ref_v1.images, rendered.images, codec=builtin_codec("gcps-v1"))
    np.testing.assert_array_equal(today.z_mm, named.z_mm)
    np.testing.assert_array_equal(today.gray_z_mm, named.gray_z_mm)
    assert named.decoding is None and named.codec_name == "gcps-v1"


def test_codec_without_u_or_a_stack_unlike_the_codec_is_refused(noise_free_reference):
    _, ref_codec = noise_free_reference
    v_only = codec_from_dict(
        {
            "codec": "gcps-codec/1",
            "frames": 24,
            "projector": {"width": PROJ_W, "height": PROJ_H},
            "white": [22],
            "black": [23],
            "axes": {"v": CODEC.to_dict()["axes"]["u"]},
        }
    )
    with pytest.raises(ValueError, match="does not code the projector's u axis"):
        measure(RIG, ref_codec, ref_codec, codec=v_only)
    with pytest.raises(ValueError, match="holds 23 frames but the codec describes 24"):
        measure(RIG, ref_codec, ref_codec[:23], codec=CODEC)
    with pytest.raises(ValueError, match="the object frames are 320x480 px but the rig's camera is 640x480 px"):
        measure(RIG, ref_codec, np.ascontiguousarray(ref_codec[:, :, :320]), codec=CODEC)
    with pytest.raises(ValueError, match="smoothing_px applies to the paper's fused gcps-v1 decoder only"):
        measure(RIG, ref_codec, ref_codec, MeasureOptions(gcps_v1=GcpsV1Options(smoothing_px=1.0)), codec=CODEC)


# ------------------------------------------------------------------ gcps measure --codec
def write_capture(folder, images: np.ndarray, codec: Codec | None) -> str:
    """A capture folder: frames NN.png in codec order, and the codec's codec.json when given."""
    import cv2

    from metrology.core.codecs import write_codec

    folder.mkdir()
    for index, image in enumerate(images):
        assert cv2.imwrite(str(folder / f"{index:02d}.png"), image)
    if codec is not None:
        write_codec(codec, folder / "codec.json")
    return str(folder)


@pytest.mark.slow
def test_cli_measures_a_codec_capture_with_its_codec_json_or_codec_option(tmp_path, noise_free_reference):
    from metrology.cli import main
    from metrology.core.codecs import write_codec
    from metrology.core.io import write_rig

    _, ref_codec = noise_free_reference
    rendered, images = render_both("plane", SimulationOptions.noise_free_16bit(), z_mm=30.0)
    rig = str(tmp_path / "rig.json")
    write_rig(RIG, rig)
    ref = write_capture(tmp_path / "ref", ref_codec, CODEC)
    obj = write_capture(tmp_path / "obj", images, CODEC)
    out, report = tmp_path / "z.npy", tmp_path / "z.json"
    args = ["--quiet", "measure", "--rig", rig, "--reference", ref, "--object", obj, "--out", str(out)]
    assert main([*args, "--json", str(report)]) == 0
    z = np.load(out)
    valid = np.isfinite(z)
    assert valid.sum() > 0.8 * rendered.lit.sum()
    assert np.abs(z[valid] - rendered.truth_mm[valid]).max() < 1e-3
    data = json.loads(report.read_text())
    assert data["codec"]["codec"] == "gcps-codec/1" and data["decoding"]["axes"]["u"]["decoded"] > 0
    # the same frames without codec.json, the codec given by --codec
    bare_ref = write_capture(tmp_path / "bare_ref", ref_codec, None)
    bare_obj = write_capture(tmp_path / "bare_obj", images, None)
    write_codec(CODEC, tmp_path / "codec.json")
    out2 = tmp_path / "z2.npy"
    bare = ["--quiet", "measure", "--rig", rig, "--reference", bare_ref, "--object", bare_obj, "--out", str(out2)]
    assert main([*bare, "--codec", str(tmp_path / "codec.json")]) == 0
    np.testing.assert_array_equal(np.load(out2), z)


def test_cli_refuses_a_codec_without_u_and_mismatched_stacks(tmp_path, noise_free_reference, capsys):
    from metrology.cli import main
    from metrology.core.codecs import write_codec
    from metrology.core.io import write_rig

    _, ref_codec = noise_free_reference
    rig = str(tmp_path / "rig.json")
    write_rig(RIG, rig)
    ref = write_capture(tmp_path / "ref", ref_codec, None)
    short = write_capture(tmp_path / "short", ref_codec[:23], None)
    v_only = dict(CODEC.to_dict())
    v_only["axes"] = {"v": v_only["axes"]["u"]}
    (tmp_path / "v.json").write_text(json.dumps(v_only))
    write_codec(CODEC, tmp_path / "codec.json")
    out = tmp_path / "z.npy"
    base = ["--quiet", "measure", "--rig", rig, "--reference", ref, "--out", str(out)]
    assert main([*base, "--object", ref, "--codec", str(tmp_path / "v.json")]) == 2
    assert "does not code the projector's u axis" in capsys.readouterr().err
    assert main([*base, "--object", short, "--codec", str(tmp_path / "codec.json")]) == 2
    assert "holds 23 image files but the codec describes 24 frames" in capsys.readouterr().err
    assert not out.exists()


# ------------------------------------------------------------------ per-point uncertainty
SMALL = Rig(L_mm=1022.0, d_mm=352.0, alpha_rad=0.332, fw_mm=500.0, nlp=128, width_px=160, height_px=120)


def sigma_against_scatter(use_codec: bool, renders: int = 30) -> tuple[float, float, int]:
    """Median predicted sigma and median observed per-pixel scatter of ``renders`` realistic 8-bit
    renders of a plane 30 mm high (one ray per pixel), against one kept reference."""
    from metrology.core.measure import prepare_reference

    opts = SimulationOptions.realistic_8bit(supersample=1)
    scene = make_scene("plane", SMALL, z_mm=30.0)
    ref = render_stack(SMALL, make_scene("reference", SMALL), opts.with_changes(seed=999))
    if use_codec:
        u, _ = crossed_rig_truth(ref, SMALL, PROJ_W, PROJ_H)
        reference: Any = prepare_reference(SMALL, render_codec(CODEC, u, None, opts, seed=999), CODEC)
    else:
        reference = prepare_reference(SMALL, ref.images)
    options = MeasureOptions(gray_only=False, sigma=True)
    heights, sigmas = [], []
    for seed in range(renders):
        rendered = render_stack(SMALL, scene, opts.with_changes(seed=seed))
        if use_codec:
            u, _ = crossed_rig_truth(rendered, SMALL, PROJ_W, PROJ_H)
            result = measure(SMALL, reference, render_codec(CODEC, u, None, opts, seed=seed), options, codec=CODEC)
        else:
            result = measure(SMALL, reference, rendered.images, options)
        assert result.sigma_mm is not None
        assert np.array_equal(np.isfinite(result.sigma_mm), np.isfinite(result.z_mm))
        heights.append(result.z_mm)
        sigmas.append(result.sigma_mm)
    z, s = np.array(heights), np.array(sigmas)
    everywhere = np.isfinite(z).all(axis=0)
    observed = z[:, everywhere].std(axis=0, ddof=1)
    predicted = s[:, everywhere].mean(axis=0)
    return float(np.median(predicted)), float(np.median(observed)), int(everywhere.sum())


def test_gcps_v1_sigma_matches_the_scatter_of_30_realistic_renders():
    predicted, observed, pixels = sigma_against_scatter(use_codec=False)
    assert pixels > 0.8 * SMALL.width_px * SMALL.height_px
    # measured: 0.997 (0.1087 mm predicted, 0.1090 mm observed); issue 12 asks for 15 %
    assert abs(predicted / observed - 1) < 0.15, (predicted, observed)


@pytest.mark.slow
def test_codec_sigma_matches_the_scatter_of_30_realistic_renders():
    predicted, observed, pixels = sigma_against_scatter(use_codec=True)
    assert pixels > 0.8 * SMALL.width_px * SMALL.height_px
    # measured: 1.000 (0.0630 mm both); 12 steps at gcps-v1's period: sqrt(3) below gcps-v1's 0.109 mm
    assert abs(predicted / observed - 1) < 0.15, (predicted, observed)
    assert 0.45 < observed / 0.109 < 0.70


def test_sigma_needs_a_noise_estimate(noise_free_reference):
    three = CODEC.to_dict()
    three["axes"]["u"]["phase"][0]["frames"] = [0, 1, 2]
    three["axes"]["u"]["gray"]["frames"] = [3, 4, 5, 6, 7]
    three["axes"]["u"]["gray"]["inverse_frames"] = [8, 9, 10, 11, 12]
    three.update(frames=15, white=[13], black=[14])
    codec = codec_from_dict(three)
    rendered = render_stack(RIG, make_scene("reference"), SimulationOptions.noise_free_16bit())
    u, _ = crossed_rig_truth(rendered, RIG, PROJ_W, PROJ_H)
    images = render_codec(codec, u, None)
    with pytest.raises(ValueError, match="N >= 4 steps"):
        measure(RIG, images, images, MeasureOptions(sigma=True), codec=codec)


def test_cli_writes_points_and_sigma_and_drops_points_above_max_sigma(tmp_path):
    from metrology.cli import main
    from metrology.core.geometry.crossed_axes import points_from_heights
    from metrology.core.io import write_rig, write_stack

    opts = SimulationOptions.realistic_8bit(supersample=1)
    rig = str(tmp_path / "rig.json")
    write_rig(SMALL, rig)
    write_stack(render_stack(SMALL, make_scene("reference", SMALL), opts.with_changes(seed=5)).images, tmp_path / "r")
    write_stack(render_stack(SMALL, make_scene("sphere", SMALL), opts.with_changes(seed=6)).images, tmp_path / "o")
    z_path, xyz_path, sigma_path = tmp_path / "z.npy", tmp_path / "xyz.npy", tmp_path / "s.npy"
    base = ["--quiet", "measure", "--rig", rig, "--reference", str(tmp_path / "r"), "--object", str(tmp_path / "o")]
    assert main([*base, "--out", str(z_path), "--xyz", str(xyz_path), "--sigma", str(sigma_path)]) == 0
    z, xyz, sigma = np.load(z_path), np.load(xyz_path), np.load(sigma_path)
    assert xyz.shape == (*SMALL.shape, 3) and xyz.dtype == np.float32 and sigma.dtype == np.float32
    valid = np.isfinite(z)
    assert valid.mean() > 0.5 and np.array_equal(np.isfinite(sigma), valid)
    np.testing.assert_allclose(xyz[valid], points_from_heights(SMALL, z)[valid], atol=1e-4)
    # 8-bit, 1.5 grey levels: about 0.1 mm per point (the plane's measured scatter, test above)
    assert 0.05 < np.median(sigma[valid]) < 0.2
    limit = float(np.median(sigma[valid]))
    kept_path = tmp_path / "kept.npy"
    assert main([*base, "--out", str(kept_path), "--max-sigma", str(limit)]) == 0
    kept = np.load(kept_path)
    assert np.isfinite(kept).sum() == (valid & (sigma <= np.float32(limit))).sum()
    assert main([*base, "--out", str(kept_path), "--max-sigma", "-1"]) == 2
