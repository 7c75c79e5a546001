"""Old commit against new commit, interleaved in one run: the measurement benchmarks' rows side by side.

    .venv/bin/python benchmarks/ab.py --old ac75eb3 --new HEAD                  # 15 rounds of decode, codecs, pinhole
    .venv/bin/python benchmarks/ab.py --old ac75eb3 --new HEAD --benches decode --rounds 21
    .venv/bin/python benchmarks/ab.py --old ac75eb3 --new HEAD --benches decode,codecs --codec-rows 24,32,42

Each commit is checked out in a temporary git worktree (``--old-tree``/``--new-tree`` use an
existing checkout instead) and runs *its own* benchmark scripts (``benchmarks/decode.py``,
``codecs.py``, ``pinhole.py``: their APIs may differ between the commits), in a fresh process
with the same interpreter and packages. A round runs every benchmark once per commit, old and
new in a random order, each run timing every row ``--repeats`` times (its median is the round's
sample); ``--rounds`` rounds give each row that many interleaved samples per commit, so load on
a shared machine hits both commits alike. Printed per row: the median of the rounds' samples of
each commit and their ratio new / old; the ``memory bound`` rows (a copy of the bytes a row must
touch) are the control, whose ratio shows the noise of the run. Exit status 1 when a row (not a
control) is slower than ``--tolerance`` (default 5 %).
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
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

Samples = dict[str, float]
"""Seconds per row of one benchmark run."""


def decode_rows(out: str, json_path: Path) -> Samples:
    return {f"decode: {k}": v for k, v in json.loads(json_path.read_text())[0]["seconds"].items()}


def codecs_rows(out: str, json_path: Path) -> Samples:
    data = json.loads(out[out.index("\n{") + 1 :] if not out.startswith("{") else out)
    rows: Samples = {}
    for label, row in data["rows"].items():
        rows[f"codecs: {label}, decode"] = row["decode_ms"] / 1e3
        rows[f"codecs: {label}, coordinates only"] = row["coordinates_only_ms"] / 1e3
        rows[f"codecs: {label}, memory bound"] = row["memory_bound_ms"] / 1e3
    return rows


def pinhole_rows(out: str, json_path: Path) -> Samples:
    data = json.loads(out.strip().splitlines()[-1])
    return {f"pinhole: {k}": v for k, v in data["seconds"].items()}


CODEC_ROWS: list[str] = []
"""``--rows`` of ``codecs.py`` when ``--codec-rows`` is given (else its default rows)."""

BENCHES: dict[str, tuple[Callable[[int, Path], list[str]], Callable[[str, Path], Samples]]] = {
    "decode": (
        lambda repeats, js: [
            "decode.py",
            "--sizes",
            "1280x1024",
            "--no-opencv",
            "--repeats",
            str(repeats),
            "--json",
            str(js),
        ],
        decode_rows,
    ),
    "codecs": (
        lambda repeats, js: ["codecs.py", "--no-opencv", "--repeats", str(repeats), *CODEC_ROWS],
        codecs_rows,
    ),
    "pinhole": (lambda repeats, js: ["pinhole.py", "--repeats", str(repeats)], pinhole_rows),
}
"""Each benchmark: its command line (after ``benchmarks/``) and the parser of its output."""


def is_control(row: str) -> bool:
    return "memory bound" in row or "cv2." in row


def run_once(tree: Path, bench: str, repeats: int) -> Samples:
    command, parse = BENCHES[bench]
    with tempfile.TemporaryDirectory() as tmp:
        js = Path(tmp) / "out.json"
        args = command(repeats, js)
        env = {**os.environ, "PYTHONPATH": str(tree)}
        done = subprocess.run(
            [sys.executable, str(tree / "benchmarks" / args[0]), *args[1:]],
            cwd=tree,
            env=env,
            capture_output=True,
            text=True,
            timeout=3600,
        )
        if done.returncode != 0:
            raise SystemExit(f"{bench} failed in {tree}:\n{done.stderr[-3000:]}")
        return parse(done.stdout, js)


def worktree(rev: str, where: Path) -> Path:
    path = where / rev.replace("/", "_")
    subprocess.run(
        ["git", "-C", str(ROOT), "worktree", "add", "--detach", str(path), rev], check=True, capture_output=True
    )
    return path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--old", default="HEAD~1", help="the commit before (default HEAD~1)")
    parser.add_argument("--new", default="HEAD", help="the commit to compare (default HEAD)")
    parser.add_argument("--old-tree", type=Path, help="an existing checkout of the old commit")
    parser.add_argument("--new-tree", type=Path, help="an existing checkout of the new commit (e.g. the working tree)")
    parser.add_argument("--benches", default=",".join(BENCHES))
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--repeats", type=int, default=3, help="timed runs of each row per benchmark run")
    parser.add_argument("--tolerance", type=float, default=0.05)
    parser.add_argument("--json", type=Path, help="write every sample here")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--codec-rows",
        help="codecs.py's stacks only, e.g. 24,32,42 (the rows both commits have; rendering them is most of its time)",
    )
    args = parser.parse_args()
    if args.codec_rows:
        CODEC_ROWS[:] = ["--rows", args.codec_rows]
    benches = args.benches.split(",")
    unknown = sorted(set(benches) - set(BENCHES))
    if unknown:
        parser.error(f"unknown benchmark(s) {', '.join(unknown)}; known: {', '.join(BENCHES)}")

    with tempfile.TemporaryDirectory(prefix="gcps-ab-") as tmp:
        made: list[Path] = []
        trees = {}
        for side, rev, given in (("old", args.old, args.old_tree), ("new", args.new, args.new_tree)):
            if given is None:
                given = worktree(rev, Path(tmp))
                made.append(given)
            trees[side] = given.resolve()
        try:
            samples: dict[str, dict[str, list[float]]] = {"old": {}, "new": {}}
            rng = random.Random(args.seed)
            for round_index in range(args.rounds):
                for bench in benches:
                    sides = ["old", "new"]
                    rng.shuffle(sides)
                    for side in sides:
                        for row, seconds in run_once(trees[side], bench, args.repeats).items():
                            samples[side].setdefault(row, []).append(seconds)
                print(f"round {round_index + 1}/{args.rounds} done", file=sys.stderr, flush=True)
                if args.json:  # the samples so far, should the run be cut short
                    args.json.write_text(json.dumps({"samples": samples, "rounds_done": round_index + 1}))
        finally:
            for path in made:
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(path)], check=False)

    print(f"old {args.old} ({trees['old']}), new {args.new} ({trees['new']})")
    print(f"medians of {args.rounds} interleaved rounds (each the median of {args.repeats} runs)\n")
    print(f"{'row':62s} {'old ms':>9s} {'new ms':>9s} {'new/old':>8s}")
    slower = []
    summary = {}
    for row in sorted(set(samples["old"]) & set(samples["new"])):
        old, new = statistics.median(samples["old"][row]), statistics.median(samples["new"][row])
        ratio = new / old
        flag = ""
        if not is_control(row) and ratio > 1 + args.tolerance:
            slower.append(row)
            flag = "  SLOWER"
        elif is_control(row):
            flag = "  (control)"
        summary[row] = {"old_s": old, "new_s": new, "ratio": ratio}
        print(f"{row:62s} {old * 1e3:9.2f} {new * 1e3:9.2f} {ratio:8.3f}{flag}")
    missing = sorted(set(samples["old"]) ^ set(samples["new"]))
    if missing:
        print(f"\nrows of one commit only: {', '.join(missing)}")
    if args.json:
        args.json.write_text(
            json.dumps({"summary": summary, "samples": samples, "args": vars(args)}, default=str, indent=1)
        )
    if slower:
        print(f"\n{len(slower)} row(s) more than {args.tolerance:.0%} slower: {', '.join(slower)}")
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
