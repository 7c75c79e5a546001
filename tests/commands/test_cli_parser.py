"""``gcps`` builds only the parser of the subcommand its arguments name (metrology/cli.py,
``build_parser``): the same parse as with every subcommand registered, every subcommand where the
arguments name none (help, an unknown command)."""

from __future__ import annotations

import argparse

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
