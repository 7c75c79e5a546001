"""``gcps`` builds only the parser of the subcommand its arguments name (metrology/cli.py,
``build_parser``): the same parse as with every subcommand registered, every subcommand where the
arguments name none (help, an unknown command)."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

import pytest

from metrology.cli import _command, build_parser
from metrology.commands import SUBCOMMANDS

ARGVS = [
    ["measure", "--rig", "r.json", "--reference", "ref", "--object", "obj", "--out", "z.npy"],
    ["--quiet", "measure", "--rig", "r.json", "--object", "obj", "--xyz", "p.npy", "--triangulate", "v"],
    ["decode", "cap", "--out", "uv.npz"],
    ["calibrate-procam", "--help"],
    ["cache", "info"],
    ["rig", "import", "--help"],
]


def parse(parser: argparse.ArgumentParser, argv: list[str]) -> argparse.Namespace | str:
    """The namespace, or what the parser printed and its exit status where it exits."""
    try:
        return parser.parse_args(argv)
    except SystemExit as exc:
        return f"exit {exc.code}"


@pytest.mark.parametrize("argv", ARGVS)
def test_one_subcommand_parses_as_all_of_them(argv, capsys):
    assert _command(argv) is not None
    one = parse(build_parser(argv), argv)
    printed_one = capsys.readouterr()
    every = parse(build_parser(), argv)
    printed_every = capsys.readouterr()
    assert one == every
    assert printed_one == printed_every


def test_the_subcommand_named():
    assert _command(["--quiet", "calibrate-procam", "--x"]) == "calibrate_procam"
    assert _command(["measure"]) == "measure"
    assert _command(None) is None
    assert _command([]) is None and _command(["--help"]) is None
    assert _command(["calibrate_procam"]) is None  # not a command's name: the full parser refuses it
    assert _command(["nope", "measure"]) is None
    only = build_parser(["measure"])
    (sub,) = [a for a in only._actions if isinstance(a, argparse._SubParsersAction)]
    assert list(sub.choices) == ["measure"]
    (sub,) = [a for a in build_parser(["--help"])._actions if isinstance(a, argparse._SubParsersAction)]
    assert len(sub.choices) == len(SUBCOMMANDS)


def test_an_unknown_command_lists_every_subcommand(capsys):
    argv = ["calibrate_procam"]
    assert parse(build_parser(argv), argv) == "exit 2"
    err = capsys.readouterr().err
    assert "invalid choice: 'calibrate_procam'" in err and "'calibrate-procam'" in err and "'inspect'" in err


TEARDOWN = (
    "import sys\n"
    "LEFT_OPEN = open({left!r}, 'w')\n"  # buffered, never closed: flushed by the interpreter's teardown
    "LEFT_OPEN.write('torn down')\n"
    "{before}"
    "import atexit\n"
    "from metrology.cli import run\n"
    "atexit.register(lambda: print('callback', flush=True))\n"
    "sys.argv[1:] = {argv!r}\n"
    "run()\n"
)


@pytest.mark.parametrize("first", [False, True])
def test_a_gcps_process_ends_after_its_exit_callbacks_without_the_teardown(tmp_path, first):
    """``run`` (the console script) ends the process after every exit callback and the threads,
    with the command's status and its output flushed, skipping the modules' teardown; not where an
    exit callback was registered before ``metrology.cli`` was imported (that one then runs too)."""
    before = "import atexit\natexit.register(lambda: print('first', flush=True))\n" if first else ""
    env = {**os.environ, "GCPS_LOCAL_CACHE_DIR": str(tmp_path / "cache")}
    bad = ["measure", "--rig", str(tmp_path / "none.json"), "--object", "obj", "--out", "z.npy"]
    for argv, status in ((["cache", "info"], 0), (bad, 2)):
        left = tmp_path / "left_open.txt"
        code = TEARDOWN.format(before=before, argv=argv, left=str(left))
        done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
        lines = done.stdout.splitlines()
        assert done.returncode == status, done.stderr
        assert "callback" in lines and ("first" in lines) == first
        assert left.read_text() == ("torn down" if first else "")  # no teardown: the buffer is lost
        if status == 0:
            assert json.loads(lines[0])  # the command's summary, flushed
        else:
            assert done.stderr.startswith("gcps: error: ") and done.stderr.count("\n") == 1
