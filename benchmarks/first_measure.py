"""The first ``gcps measure`` of issue 22's distorted rig beside the same command with the rig's
distortion set to zero: fresh processes, empty local caches, interleaved; wall time and peak RSS.

Usage (from the repository root)::

    .venv/bin/python benchmarks/first_measure.py [--repeats 5] [--old-tree DIR]

Set-up (untimed, in a temporary folder): the rig ``examples/distorted-pinhole-rig.json``
(1280x1024 camera, 1920x1080 projector, both strongly distorted), the same rig with both
``dist`` lists empty, issue 22's u-only 18-frame codec (12 phase frames of period 60, shift +1,
origin 30; a 6-bit gray code of 30-px words, MSB first) and one realistic 8-bit capture of a
sphere 640-741 mm away rendered through the distorted rig (``gcps simulate --preset realistic
--supersample 1``). Both commands measure that capture (the distortion-free one with the wrong
rig: only its time and memory count).

Each repeat runs ``gcps measure --rig R --object CAPTURE --out depth.npy`` once per rig, in a
random order, every process with its own new, empty ``GCPS_LOCAL_CACHE_DIR``; the wall time
is the child's from start to exit, its CPU time ``ru_utime + ru_stime`` (all its threads;
less sensitive to a loaded machine than the wall time) and its peak RSS ``ru_maxrss`` (``os.wait4``). A last run
of the distorted rig with the local cache its first run left (a second process) is timed too.
Prints the medians, the ratios distorted / distortion-free and a JSON line.

``--old-tree DIR``: a checkout of an older commit (e.g. ``git archive b2c99ec | tar -x -C DIR``);
its ``gcps measure`` of the distorted rig runs once and the depths of the two commits are
compared on the pixels both measured (issue 22: within 1 um).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RIG_FILE = ROOT / "examples" / "distorted-pinhole-rig.json"

CODEC = {
    "codec": "gcps-codec/1",
    "frames": 18,
    "projector": {"width": 1920, "height": 1080},
    "axes": {
        "u": {
            "phase": [{"frames": list(range(12)), "period": 60.0, "shift": 1, "origin": 30.0}],
            "gray": {"frames": list(range(12, 18)), "order": "msb_first", "word": 30.0, "origin": 0.0},
        }
    },
}
"""Issue 22's u-only codec."""


def gcps(tree: Path, *args: str, env: dict[str, str] | None = None) -> tuple[float, int, float]:
    """Run ``gcps ARGS`` of the source tree ``tree`` in a fresh process: (wall seconds, peak RSS
    bytes, CPU seconds: user + system, all threads)."""
    code = "import sys; from metrology.cli import main; sys.argv[0] = 'gcps'; sys.exit(main())"
    full_env = {**os.environ, "PYTHONPATH": str(tree), **(env or {})}
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-c", code, *args], cwd=tree, env=full_env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    assert proc.stderr is not None
    _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - t0
    err = proc.stderr.read().decode(errors="replace")
    proc.stderr.close()
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"gcps {' '.join(args)} failed ({proc.returncode}):\n{err[-2000:]}")
    return seconds, usage.ru_maxrss * 1024, usage.ru_utime + usage.ru_stime


def set_up(folder: Path) -> tuple[Path, Path, Path]:
    """The distorted rig file, its distortion-free twin and a capture (in ``folder``)."""
    rig = json.loads(RIG_FILE.read_text())
    plain = {**rig, "camera": {**rig["camera"], "dist": []}, "projector": {**rig["projector"], "dist": []}}
    distorted_path, plain_path = folder / "distorted.json", folder / "plain.json"
    distorted_path.write_text(json.dumps(rig))
    plain_path.write_text(json.dumps(plain))
    codec_path = folder / "u18.codec.json"
    codec_path.write_text(json.dumps(CODEC))
    capture = folder / "sphere"
    gcps(
        ROOT,
        *("simulate", "--rig", str(distorted_path), "--codec", str(codec_path), "--scene", "sphere"),
        *("--distance-mm", "740", "--preset", "realistic", "--supersample", "1", "--out", str(capture)),
        env={"GCPS_LOCAL_CACHE_DIR": str(folder / "simulate-cache")},
    )
    return distorted_path, plain_path, capture


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--old-tree", type=Path, default=None)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory(prefix="gcps-first-measure-") as tmp:
        folder = Path(tmp)
        rigs = dict(zip(("distorted", "plain"), set_up(folder)[:2], strict=True))
        capture = folder / "sphere"
        times: dict[str, list[float]] = {name: [] for name in rigs}
        rss: dict[str, list[int]] = {name: [] for name in rigs}
        cpu: dict[str, list[float]] = {name: [] for name in rigs}
        last_cache = None
        for i in range(args.repeats):
            order = list(rigs)
            rng.shuffle(order)
            for name in order:
                cache = folder / f"cache-{name}-{i}"
                out = folder / f"{name}-{i}.npy"
                seconds, peak, cpu_s = gcps(
                    ROOT,
                    *("measure", "--rig", str(rigs[name]), "--object", str(capture), "--out", str(out)),
                    env={"GCPS_LOCAL_CACHE_DIR": str(cache)},
                )
                times[name].append(seconds)
                rss[name].append(peak)
                cpu[name].append(cpu_s)
                if name == "distorted":
                    last_cache = cache
                print(
                    f"round {i + 1}: {name:9s} {seconds:6.2f} s (CPU {cpu_s:5.2f} s), peak RSS {peak / 2**20:6.0f} MiB",
                    flush=True,
                )
        warm, _, _ = gcps(
            ROOT,
            *("measure", "--rig", str(rigs["distorted"]), "--object", str(capture), "--out", str(folder / "warm.npy")),
            env={"GCPS_LOCAL_CACHE_DIR": str(last_cache)},
        )
        med = {name: statistics.median(ts) for name, ts in times.items()}
        med_rss = {name: statistics.median(r) for name, r in rss.items()}
        med_cpu = {name: statistics.median(c) for name, c in cpu.items()}
        result: dict[str, float] = {
            "distorted_s": med["distorted"],
            "plain_s": med["plain"],
            "time_ratio": med["distorted"] / med["plain"],
            "distorted_rss_mib": med_rss["distorted"] / 2**20,
            "plain_rss_mib": med_rss["plain"] / 2**20,
            "rss_ratio": med_rss["distorted"] / med_rss["plain"],
            "second_process_s": warm,
            "distorted_cpu_s": med_cpu["distorted"],
            "plain_cpu_s": med_cpu["plain"],
            "cpu_ratio": med_cpu["distorted"] / med_cpu["plain"],
        }
        print(
            f"first gcps measure, medians of {args.repeats}: distorted rig {med['distorted']:.2f} s "
            f"({result['distorted_rss_mib']:.0f} MiB), distortion zero {med['plain']:.2f} s "
            f"({result['plain_rss_mib']:.0f} MiB): time ratio {result['time_ratio']:.2f}, "
            f"RSS ratio {result['rss_ratio']:.2f}; CPU time {med_cpu['distorted']:.2f} s and {med_cpu['plain']:.2f} s "
            f"(ratio {result['cpu_ratio']:.2f}); a second process (cache warm) {warm:.2f} s"
        )
        if args.old_tree is not None:
            old_out = folder / "old.npy"
            gcps(
                args.old_tree.resolve(),
                *("measure", "--rig", str(rigs["distorted"]), "--object", str(capture), "--out", str(old_out)),
                env={"GCPS_LOCAL_CACHE_DIR": str(folder / "cache-old")},
            )
            new, old = np.load(folder / "distorted-0.npy"), np.load(old_out)
            both = np.isfinite(new) & np.isfinite(old)
            diff = float(np.abs(new[both] - old[both]).max()) if both.any() else float("nan")
            result.update(
                {
                    "old_tree_worst_um": diff * 1e3,
                    "old_tree_common_px": int(both.sum()),
                    "only_new_px": int((np.isfinite(new) & ~np.isfinite(old)).sum()),
                    "only_old_px": int((np.isfinite(old) & ~np.isfinite(new)).sum()),
                }
            )
            print(
                f"depths against {args.old_tree}: worst {diff * 1e3:.3f} um over {int(both.sum())} pixels "
                f"(measured by one only: new {result['only_new_px']}, old {result['only_old_px']})"
            )
        print(json.dumps(result))


if __name__ == "__main__":
    main()
