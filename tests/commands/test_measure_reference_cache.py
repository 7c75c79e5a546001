"""``gcps measure`` keeps the decoded reference in the local cache, keyed by the capture's files: a
second process measuring against the same reference reads it instead of reading and decoding its
images, and writes the same heights; a changed file decodes again."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import cv2
import numpy as np

from metrology.cli import main
from metrology.core.io import write_rig
from tests.commands.rigs import RIG


def test_a_second_process_reads_the_kept_reference(tmp_path) -> None:
    write_rig(RIG, tmp_path / "rig.json")
    for scene, extra in (("reference", []), ("block", ["--z-mm", "40"])):
        args = ["--quiet", "simulate", "--rig", str(tmp_path / "rig.json"), "--scene", scene]
        assert main([*args, *extra, "--out", str(tmp_path / scene)]) == 0
    env = {**os.environ, "GCPS_LOCAL_CACHE_DIR": str(tmp_path / "cache")}
    reports = []
    for run in range(3):
        if run == 2:  # one grey level of one pixel of one reference image changed
            image = cv2.imread(str(tmp_path / "reference" / "PS_1.png"), cv2.IMREAD_UNCHANGED)
            image[3, 3] ^= 1
            assert cv2.imwrite(str(tmp_path / "reference" / "PS_1.png"), image)
        out, stats = tmp_path / f"z{run}.npy", tmp_path / f"s{run}.json"
        command = [sys.executable, "-m", "metrology.cli", "--quiet", "measure", "--rig", str(tmp_path / "rig.json")]
        command += ["--reference", str(tmp_path / "reference"), "--object", str(tmp_path / "block")]
        subprocess.run([*command, "--out", str(out), "--json", str(stats)], env=env, check=True, timeout=300)
        reports.append(json.loads(stats.read_text()))
    first, second, third = (r["reference_cache"] for r in reports)
    assert first["hit"] is False and first["decode_s"] > 0 and first["key"] == "files" and first["read_s"] > 0
    assert second["hit"] is True and second["load_s"] > 0 and "read_s" not in second  # no image read
    assert third["hit"] is False and third["read_s"] > 0  # the changed file: read and decoded again
    assert "measure.reference_decode_s" in reports[0]["timings_s"]
    assert (
        "measure.reference_decode_s" not in reports[1]["timings_s"] and reports[1]["timings_s"]["reference_cache_s"] > 0
    )
    np.testing.assert_array_equal(np.load(tmp_path / "z0.npy"), np.load(tmp_path / "z1.npy"))
