"""The gcps command line (docs/command-line.md): round trips and every bad input (exit 2, one line, no output)."""

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from metrology.cli import main
from metrology.core.geometry.crossed_axes import Rig
from metrology.core.io import read_stack, write_rig, write_stack
from tests.commands.rigs import RIG


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """A rig file, a noise-free reference and a 40 mm block (16-bit) with its truth."""
    root = tmp_path_factory.mktemp("captures")
    write_rig(RIG, root / "rig.json")
    assert (
        main(
            [
                "--quiet",
                "simulate",
                "--rig",
                str(root / "rig.json"),
                "--scene",
                "reference",
                "--preset",
                "noise-free",
                "--out",
                str(root / "ref"),
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "--quiet",
                "simulate",
                "--rig",
                str(root / "rig.json"),
                "--scene",
                "block",
                "--z-mm",
                "40",
                "--preset",
                "noise-free",
                "--out",
                str(root / "block.zip"),
                "--truth",
                str(root / "truth.npy"),
            ]
        )
        == 0
    )
    return root


def run(*args: str) -> int:
    return main(["--quiet", *args])


def test_patterns(tmp_path):
    assert run("patterns", "--width", "1024", "--height", "768", "--out", str(tmp_path / "p")) == 0
    stack = read_stack(tmp_path / "p")
    assert stack.images.shape == (11, 768, 1024) and stack.bit_depth == 8


def test_measure_noise_free_is_exact(captures, tmp_path):
    out, mesh, stats = tmp_path / "h.npy", tmp_path / "m.ply", tmp_path / "s.json"
    assert (
        run(
            "measure",
            "--rig",
            str(captures / "rig.json"),
            "--reference",
            str(captures / "ref"),
            "--object",
            str(captures / "block.zip"),
            "--out",
            str(out),
            "--mesh",
            str(mesh),
            "--json",
            str(stats),
        )
        == 0
    )
    z, truth = np.load(out), np.load(captures / "truth.npy")
    assert z.dtype == np.float32 and z.shape == RIG.shape
    both = np.isfinite(z) & np.isfinite(truth)
    assert both.sum() > 0.9 * np.isfinite(truth).sum()
    assert np.abs(z[both] - truth[both]).max() < 1e-3  # under a micrometre
    assert mesh.stat().st_size > 0
    report = json.loads(stats.read_text())
    assert report["valid_pixels"] == int(np.isfinite(z).sum()) and report["rig"]["L_mm"] == 1022.0


def test_calibrate_from_the_papers_rough_start(captures, tmp_path):
    rough = RIG.with_parameters(L_mm=1080.0, alpha_rad=0.4871)
    write_rig(rough, tmp_path / "rough.json")
    for method in ("lsq", "paper"):
        out = tmp_path / f"{method}.json"
        assert (
            run(
                "calibrate",
                "--rig",
                str(tmp_path / "rough.json"),
                "--reference",
                str(captures / "ref"),
                "--master",
                str(captures / "block.zip"),
                "--master-height",
                "40",
                "--method",
                method,
                "--out",
                str(out),
            )
            == 0
        )
        calibrated = json.loads(out.read_text())
        assert abs(calibrated["L_mm"] - 1022.0) < 0.2, method
        assert abs(calibrated["alpha_rad"] - 0.332) < 0.001, method
        assert calibrated["calibration"]["method"] == method and calibrated["calibration"]["history"]
        Rig.from_dict(calibrated)  # gcps measure accepts it


def test_characterize_and_sensitivity(captures, tmp_path):
    rig = str(captures / "rig.json")
    assert (
        run(
            "simulate",
            "--rig",
            rig,
            "--scene",
            "stage",
            "--z-in",
            "0:8:4",
            "--repeats",
            "2",
            "--preset",
            "noise-free",
            "--out",
            str(tmp_path / "series"),
        )
        == 0
    )
    assert (
        run(
            "characterize",
            "--rig",
            rig,
            "--reference",
            str(captures / "ref"),
            "--series",
            str(tmp_path / "series" / "series.json"),
            "--out",
            str(tmp_path / "c.json"),
        )
        == 0
    )
    report = json.loads((tmp_path / "c.json").read_text())
    assert report["z_in_mm"] == [0.0, 4.0, 8.0]
    assert len(report["test_points"]) >= 20
    assert all(abs(p["slope"] - 1) < 1e-4 for p in report["test_points"])
    assert abs(report["overall"]["mean_error_mm"]) < 1e-3
    assert run("sensitivity", "--rig", rig, "--param", "d", "--out", str(tmp_path / "s.json")) == 0
    assert "d" in json.loads((tmp_path / "s.json").read_text())["curves"]


def _stack_variants(captures: Path, tmp: Path) -> dict[str, tuple[str, str]]:
    """Bad object stacks: name -> (path, expected words in the message)."""
    ref = captures / "ref"
    variants = {}
    missing = tmp / "missing"
    shutil.copytree(ref, missing)
    (missing / "PS_3.png").unlink()
    variants["missing image"] = (str(missing), "PS_3")
    extra = tmp / "extra"
    shutil.copytree(ref, extra)
    shutil.copy(ref / "PS_3.png", extra / "PS_4.png")
    variants["extra image"] = (str(extra), "PS_4")
    wrong = tmp / "wrong"
    shutil.copytree(ref, wrong)
    (wrong / "GC_0.png").rename(wrong / "gray0.png")
    variants["wrong name"] = (str(wrong), "gray0.png")
    mixed = tmp / "mixed"
    shutil.copytree(ref, mixed)
    images = read_stack(ref).images
    write_stack(images[:, :, :100], tmp / "small")
    shutil.copy(tmp / "small" / "GC_3.png", mixed / "GC_3.png")
    variants["mismatched shapes"] = (str(mixed), "GC_3")
    variants["shape unlike the rig"] = (str(tmp / "small"), "240")
    corrupt = tmp / "corrupt"
    shutil.copytree(ref, corrupt)
    (corrupt / "PS_1.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    variants["unreadable file"] = (str(corrupt), "PS_1")
    (tmp / "notzip.zip").write_bytes(b"not a zip at all")
    variants["not a zip"] = (str(tmp / "notzip.zip"), "zip")
    with zipfile.ZipFile(tmp / "evil.zip", "w") as archive:
        for path in sorted(ref.iterdir()):
            archive.write(path, f"../{path.name}")
    variants["path traversal"] = (str(tmp / "evil.zip"), "..")
    variants["nonexistent"] = (str(tmp / "nothere"), "nothere")
    return variants


def test_every_bad_stack_exits_2_with_one_line_and_no_output(captures, tmp_path, capsys):
    for name, (path, words) in _stack_variants(captures, tmp_path).items():
        out = tmp_path / f"{name.replace(' ', '_')}.npy"
        code = main(
            [
                "measure",
                "--rig",
                str(captures / "rig.json"),
                "--reference",
                str(captures / "ref"),
                "--object",
                path,
                "--out",
                str(out),
                "--mesh",
                str(out.with_suffix(".ply")),
            ]
        )
        err = capsys.readouterr().err
        assert code == 2, name
        assert err.count("\n") == 1 and err.startswith("gcps: error: "), (name, err)
        assert words in err, (name, err)
        assert not out.exists() and not out.with_suffix(".ply").exists(), name


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"L_mm": None}, "L_mm"),
        ({"alpha_rad": 2.0}, "alpha_rad"),
        ({"nlp": 0}, "nlp"),
        ({"width_px": 320.5}, "width_px"),
    ],
)
def test_bad_rig_exits_2(captures, tmp_path, capsys, change, words):
    data = json.loads((captures / "rig.json").read_text())
    for key, value in change.items():
        if value is None:
            del data[key]
        else:
            data[key] = value
    (tmp_path / "rig.json").write_text(json.dumps(data))
    out = tmp_path / "h.npy"
    code = main(
        [
            "measure",
            "--rig",
            str(tmp_path / "rig.json"),
            "--reference",
            str(captures / "ref"),
            "--object",
            str(captures / "block.zip"),
            "--out",
            str(out),
        ]
    )
    assert code == 2 and words in capsys.readouterr().err and not out.exists()


@pytest.mark.slow
def test_installed_command_runs(captures, tmp_path):
    """The console script works as a process: exit status and stderr as external checks see them."""
    gcps = Path(sys.executable).with_name("gcps")
    result = subprocess.run(
        [
            str(gcps),
            "measure",
            "--rig",
            str(captures / "rig.json"),
            "--reference",
            "nope",
            "--object",
            "nope",
            "--out",
            str(tmp_path / "h.npy"),
        ],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 2 and result.stderr.startswith("gcps: error:")


@pytest.mark.slow
@pytest.mark.parametrize(
    ("scene", "params", "test", "extra", "key", "limit_mm"),
    [
        ("plane", ["--z-mm", "30"], "flatness", [], "flatness_rejected_mm", 0.05),
        ("sphere", ["--param", "radius_mm=50"], "probing", ["--diameter", "100"], "size_error_mm", 0.002),
        (
            "two_spheres",
            ["--param", "radius_mm=40", "--param", "spacing_mm=250"],
            "spacing",
            ["--spacing", "250"],
            "spacing_error_mm",
            0.002,
        ),
    ],
)
def test_acceptance_from_a_capture(captures, tmp_path, scene, params, test, extra, key, limit_mm):
    """VDI/VDE 2634-2 quantities from noise-free captures: the fits recover the artefacts."""
    rig = str(captures / "rig.json")
    assert (
        run(
            "simulate",
            "--rig",
            rig,
            "--scene",
            scene,
            *params,
            "--preset",
            "noise-free",
            "--out",
            str(tmp_path / "obj"),
        )
        == 0
    )
    out = tmp_path / "a.json"
    assert (
        run(
            "acceptance",
            "--rig",
            rig,
            "--reference",
            str(captures / "ref"),
            "--object",
            str(tmp_path / "obj"),
            "--test",
            test,
            *extra,
            "--out",
            str(out),
        )
        == 0
    )
    report = json.loads(out.read_text())
    assert report["test"] == test and abs(report[key]) < limit_mm, report


def test_acceptance_needs_its_calibrated_value(captures, tmp_path, capsys):
    out = tmp_path / "a.json"
    probing_the_bare_plane = [
        "acceptance", "--rig", str(captures / "rig.json"), "--reference", str(captures / "ref"),
        "--object", str(captures / "ref"), "--test", "probing", "--out", str(out),
    ]  # fmt: skip
    assert main(probing_the_bare_plane) == 2 and "--diameter" in capsys.readouterr().err
    assert main([*probing_the_bare_plane, "--diameter", "100"]) == 2
    assert "found 0 region" in capsys.readouterr().err and not out.exists()


def test_stage_range_stops_at_the_inclusive_stop(captures, tmp_path):
    out = tmp_path / "series"
    args = ["simulate", "--rig", str(captures / "rig.json"), "--scene", "stage", "--z-in", "0:8:3"]
    assert run(*args, "--preset", "noise-free", "--out", str(out)) == 0
    series = json.loads((out / "series.json").read_text())
    assert [p["z_in_mm"] for p in series["positions"]] == [0.0, 3.0, 6.0]


def test_simulate_camera_sampling(captures, tmp_path, capsys):
    """--camera-sampling centre renders the centre ray of each pixel, reported with the options;
    a value other than area/centre exits 2."""
    rig = str(captures / "rig.json")
    common = ["simulate", "--rig", rig, "--scene", "block", "--z-mm", "40", "--preset", "noise-free"]
    assert main([*common, "--supersample", "3", "--camera-sampling", "centre", "--out", str(tmp_path / "c")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["options"]["camera_sampling"] == "centre" and summary["options"]["supersample"] == 3
    # the centre ray of a 3x3 pixel is the one ray of an unsupersampled render: same images
    np.testing.assert_array_equal(read_stack(tmp_path / "c").images, read_stack(captures / "block.zip").images)
    capsys.readouterr()
    assert run(*common, "--camera-sampling", "center", "--out", str(tmp_path / "x")) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "camera_sampling" in err and "'center'" in err
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ('{"L_mm": ' + "[" * 100_000 + "]" * 100_000 + "}", "nested too deeply"),
        ('{"model": "pinhole", "T": ' + "[" * 100_000 + "]" * 100_000 + "}", "nested too deeply"),
        (
            '{"L_mm": 1e400, "d_mm": 352, "alpha_rad": 0.332, "fw_mm": 500, "nlp": 128, '
            '"width_px": 320, "height_px": 240}',
            "L_mm",
        ),
    ],
)
def test_a_deeply_nested_or_non_finite_rig_file_exits_2_with_one_line(captures, tmp_path, capsys, text, words):
    """Issue 23 item 6: no RecursionError traceback from a rig file nested 100,000 levels deep."""
    (tmp_path / "rig.json").write_text(text)
    out = tmp_path / "h.npy"
    args = ["--rig", str(tmp_path / "rig.json"), "--reference", str(captures / "ref")]
    code = main(["measure", *args, "--object", str(captures / "block.zip"), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and words in err and err.count("\n") == 1 and not out.exists(), err


@pytest.mark.parametrize(("given", "expected"), [(None, "1"), ("3", "3")])
def test_a_gcps_process_runs_openblas_on_one_thread_unless_told(given, expected):
    """numpy's OpenBLAS is told before numpy's import (its idle worker spins after it starts); an
    explicit OPENBLAS_NUM_THREADS is kept."""
    code = (
        "import sys, metrology.cli, os; assert 'numpy' not in sys.modules; import numpy; "
        "print(os.environ['OPENBLAS_NUM_THREADS'])"
    )
    env = {key: value for key, value in os.environ.items() if key != "OPENBLAS_NUM_THREADS"}
    if given is not None:
        env["OPENBLAS_NUM_THREADS"] = given
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert done.stdout.strip() == expected


def test_a_gcps_process_freezes_its_objects_at_exit():
    """The interpreter's final collections skip what the process imported (gc.freeze at exit):
    a handler registered before main() runs after main's and sees the frozen objects."""
    code = (
        "import atexit, gc, sys\n"
        "atexit.register(lambda: print('frozen', gc.get_freeze_count()))\n"
        "from metrology.cli import main\n"
        "print('before', gc.get_freeze_count())\n"
        "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    lines = dict(line.split() for line in done.stdout.splitlines() if line.startswith(("before", "frozen")))
    assert lines["before"] == "0" and int(lines["frozen"]) > 1000


def test_a_gcps_process_collects_cycles_every_50000_allocations():
    """metrology.cli raises the cyclic collector's first threshold as it is imported (its imports
    allocate no garbage; at Python's 700 a gcps measure ran 58 collections, 11 ms)."""
    import subprocess
    import sys

    code = "import gc, metrology.cli as cli; print(gc.get_threshold()[0], cli.GC_FIRST_THRESHOLD)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60)
    assert done.stdout.split() == ["50000", "50000"]
