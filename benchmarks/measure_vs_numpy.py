"""``gcps measure`` of a 1280x1024 gcps-v1 pair beside a plain numpy decode of the same pair held
in memory, in one run (issue 22, "Must show": at most 2x).

Usage (from the repository root)::

    .venv/bin/python benchmarks/measure_vs_numpy.py [--repeats 7] [--width 1280 --height 1024]

Set-up (untimed, in a temporary folder): the paper's crossed-axes rig (L 1022 mm, d 352 mm,
alpha 0.332 rad, field 500 mm, 128 light codes) on a WIDTHxHEIGHT camera, and realistic 8-bit
gcps-v1 captures of the reference plane and of a sphere (``gcps simulate --preset realistic
--supersample 1``), read once into two ``(11, H, W)`` uint8 arrays for the baseline.

Timed, interleaved in a random order per repeat:

- ``gcps measure``: ``gcps measure --rig R --reference REF --object OBJ --out H.npy`` with its
  defaults, a fresh process each time (start-up, reading the PNGs, decoding both stacks, the
  filters, writing the heights): the wall time from start to exit. Every module the command
  imports has its bytecode, as after ``pip install`` (or ``scripts/setup.sh``): the untimed
  warm-up runs the command with ``PYTHONDONTWRITEBYTECODE`` removed from its environment, so that
  Python writes the bytecode of what it imports, the package's and the installed packages'
  (numpy, OpenCV...) alike, and nothing else; a second untimed run then lists the imported modules
  whose bytecode is still missing (printed, and in the JSON: expected none).
  ``--no-bytecode`` leaves the environment as it is (with ``PYTHONDONTWRITEBYTECODE`` set,
  every process then compiles what has no bytecode yet);
- ``numpy decode``: the paper's method on the two arrays in memory, no filters, one thread:
  the phase mean ``A = (I0 + I1 + I2 + I3) / 4`` as the gray codes' threshold, the gray word
  (MSB first) to binary by prefix XOR, the four-step ``Phi = atan2(I1 - I3, I0 - I2)``, the
  combined code ``l = 4 n + (2/pi) Phi`` nearest the gray cell's centre ``l^ + 0.5`` (the
  paper's Eq. 3 unwrapping), NaN where the modulation is below 4 % of full scale or gray and
  phase disagree by more than 0.35 codes beyond the cell; then the heights against the
  reference's codes (Eqs. 14, 16, 17): ``D = L (p - t q) / (1 + q r) (l - r) / (1 + q l)``,
  ``z = L D / (d + D)``, float32.

Prints the medians of the wall time and of the CPU time (user + system, all threads: the
command's threads add up, the numpy decode has one), their ratios and a JSON line, and the
heights' agreement on the pixels both measured (a check that the baseline computes the same
thing).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from metrology.core.geometry.crossed_axes import Rig
from metrology.core.patterns import PATTERN_NAMES

ROOT = Path(__file__).resolve().parents[1]


CPU: dict[str, list[float]] = {}
"""CPU seconds (user + system, all threads) of each timed case, beside its wall time."""


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def gcps(*args: str, env: dict[str, str], write_bytecode: bool = False) -> float:
    """Wall seconds of ``gcps ARGS`` in a fresh process (stdout discarded); its CPU seconds are
    appended to ``CPU["gcps measure"]``. ``write_bytecode``: without ``PYTHONDONTWRITEBYTECODE``
    in its environment (Python writes the bytecode of the modules it imports)."""
    code = "import sys; from metrology.cli import run; sys.argv[0] = 'gcps'; run()"  # the console script's
    environment = {**os.environ, "PYTHONPATH": str(ROOT), **env}
    if write_bytecode:
        environment.pop("PYTHONDONTWRITEBYTECODE", None)
    c0 = _children_cpu()
    t0 = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-c", code, *args],
        cwd=ROOT,
        env=environment,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    seconds = time.perf_counter() - t0
    CPU.setdefault("gcps measure", []).append(_children_cpu() - c0)
    if done.returncode != 0:
        raise SystemExit(f"gcps {' '.join(args)} failed:\n{done.stderr[-2000:]}")
    return seconds


MISSING_BYTECODE = """
import atexit, importlib.util, json, os, sys
def _missing():
    paths = (getattr(m, "__file__", None) for m in list(sys.modules.values()))
    missing = sorted(
        p for p in paths
        if p and p.endswith(".py") and not os.path.exists(importlib.util.cache_from_source(p))
    )
    print(json.dumps(missing), file=sys.stderr)
atexit.register(_missing)
from metrology.cli import main
sys.argv[0] = "gcps"
sys.exit(main())
"""
"""A ``gcps`` process that prints (JSON, stderr, at exit) the source files of the modules it
imported that have no bytecode beside them (``__pycache__``)."""


def missing_bytecode(*args: str, env: dict[str, str]) -> list[str]:
    """The modules ``gcps ARGS`` imports without bytecode (their source files), in the benchmark's
    environment (untimed)."""
    done = subprocess.run(
        [sys.executable, "-c", MISSING_BYTECODE, *args],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT), **env},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        check=True,
    )
    missing: list[str] = json.loads(done.stderr.strip().splitlines()[-1])
    return missing


def read_stack(folder: Path) -> np.ndarray:
    """The eleven frames of a gcps-v1 capture, ``(11, H, W)`` uint8."""
    frames = []
    for name in PATTERN_NAMES:
        (path,) = folder.glob(f"{name}.*")
        frames.append(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE))
    return np.stack(frames)


def numpy_codes(stack: np.ndarray, min_modulation: float = 0.04 * 255, consistency: float = 0.35) -> np.ndarray:
    """The paper's decode of a ``(11, H, W)`` uint8 stack in plain numpy: light codes, float32, NaN
    where not decoded (see the module docstring)."""
    gray, phase = stack[:7], stack[7:].astype(np.float32)
    i0, i1, i2, i3 = phase
    total = i0 + i1 + i2 + i3  # 4 A
    s, c = i1 - i3, i0 - i2
    modulation = np.hypot(s, c)
    t = np.arctan2(s, c) * np.float32(2 / np.pi)  # (2/pi) Phi in [-2, 2]
    bit = gray.astype(np.float32) * 4 > total  # gray frame above the phase mean A
    word = np.zeros(stack.shape[1:], np.int32)  # binary word by prefix XOR of the gray bits, MSB first
    prev = np.zeros(stack.shape[1:], bool)
    for k in range(7):
        prev = prev ^ bit[k]
        word |= prev.astype(np.int32) << (6 - k)
    centre = word.astype(np.float32) + np.float32(0.5)
    n = np.round((centre - t) / 4)
    codes = 4 * n + t
    bad = (modulation < min_modulation) | (np.abs(codes - centre) > 0.5 + consistency)
    codes[bad] = np.nan
    return codes.astype(np.float32)


def numpy_heights(rig: Rig, ref: np.ndarray, obj: np.ndarray) -> np.ndarray:
    """Eqs. 14, 16, 17 from the codes of the reference and the object, float32 mm."""
    m = rig.mobius
    r, l = numpy_codes(ref), numpy_codes(obj)
    q = np.float32(m.q)
    slope = np.float32(m.L_mm * (m.p - m.t * m.q)) / (1 + q * r)
    disp = slope * (l - r) / (1 + q * l)
    return np.float32(rig.L_mm) * disp / (np.float32(rig.d_mm) + disp)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--height", type=int, default=1024)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--no-bytecode",
        action="store_true",
        help="keep PYTHONDONTWRITEBYTECODE in the warm-up: what has no bytecode is compiled by every process",
    )
    args = parser.parse_args()
    rng = random.Random(args.seed)
    rig = Rig(
        L_mm=1022.0, d_mm=352.0, alpha_rad=0.332, fw_mm=500.0, nlp=128, width_px=args.width, height_px=args.height
    )
    with tempfile.TemporaryDirectory(prefix="gcps-measure-vs-numpy-") as tmp:
        folder = Path(tmp)
        env = {"GCPS_LOCAL_CACHE_DIR": str(folder / "cache")}
        rig_path = folder / "rig.json"
        rig_path.write_text(rig.to_json())
        for scene in ("reference", "sphere"):
            gcps(
                *("simulate", "--rig", str(rig_path), "--scene", scene, "--out", str(folder / scene)),
                *("--preset", "realistic", "--supersample", "1"),
                env=env,
            )
        ref, obj = read_stack(folder / "reference"), read_stack(folder / "sphere")
        out = folder / "h.npy"
        command = (
            *("measure", "--rig", str(rig_path), "--reference", str(folder / "reference")),
            *("--object", str(folder / "sphere"), "--out", str(out)),
        )
        cases = {
            "gcps measure": lambda: gcps(*command, env=env),
            "numpy decode": lambda: _timed(lambda: numpy_heights(rig, ref, obj)),
        }
        # warm-up: the page cache, the kept reference, the bytecode of what the command imports
        gcps(*command, env=env, write_bytecode=not args.no_bytecode)
        cases["numpy decode"]()
        missing = missing_bytecode(*command, env=env)
        if missing:
            print(f"{len(missing)} modules imported without bytecode, e.g. {missing[:3]}")
        times: dict[str, list[float]] = {name: [] for name in cases}
        CPU.clear()  # the set-up's and the warm-up's
        for _ in range(args.repeats):
            order = list(cases)
            rng.shuffle(order)
            for name in order:
                times[name].append(cases[name]())
        med = {name: statistics.median(ts) for name, ts in times.items()}
        cpu = {name: statistics.median(CPU[name][: args.repeats]) for name in cases}
        ours, plain = np.load(out), numpy_heights(rig, ref, obj)
        both = np.isfinite(ours) & np.isfinite(plain)
        diff = np.abs(ours[both] - plain[both])
        result = {
            "size": f"{args.width}x{args.height}",
            "gcps_measure_s": med["gcps measure"],
            "numpy_decode_s": med["numpy decode"],
            "ratio": med["gcps measure"] / med["numpy decode"],
            "gcps_measure_cpu_s": cpu["gcps measure"],
            "numpy_decode_cpu_s": cpu["numpy decode"],
            "cpu_ratio": cpu["gcps measure"] / cpu["numpy decode"],
            "gcps_valid_fraction": float(np.isfinite(ours).mean()),
            "numpy_valid_fraction": float(np.isfinite(plain).mean()),
            "height_median_abs_diff_um": float(np.median(diff) * 1e3),
            "modules_without_bytecode": len(missing),
        }
        print(
            f"{result['size']}, medians of {args.repeats}: gcps measure {med['gcps measure']:.3f} s (a fresh process), "
            f"numpy decode of the pair in memory {med['numpy decode']:.3f} s: ratio {result['ratio']:.2f}; CPU time "
            f"{cpu['gcps measure']:.3f} s and {cpu['numpy decode']:.3f} s: ratio {result['cpu_ratio']:.2f}; "
            f"valid {result['gcps_valid_fraction']:.3f} (gcps, filtered) and {result['numpy_valid_fraction']:.3f} "
            f"(numpy), heights' median difference {result['height_median_abs_diff_um']:.2f} um"
        )
        print(json.dumps(result))


def _timed(fn: object) -> float:
    """Wall seconds of ``fn()``; its CPU seconds are appended to ``CPU["numpy decode"]``."""
    assert callable(fn)
    c0, t0 = time.process_time(), time.perf_counter()
    fn()
    seconds = time.perf_counter() - t0
    CPU.setdefault("numpy decode", []).append(time.process_time() - c0)
    return seconds


if __name__ == "__main__":
    main()
