"""``python -m tests.rewritten_bytecode`` writes what pytest itself would load: the same rewritten
code, in the cache file pytest reads, accepted by pytest's own reader."""

from __future__ import annotations

import marshal
from pathlib import Path

from _pytest.assertion import rewrite

from tests.rewritten_bytecode import ROOT, modules_pytest_rewrites, write_rewritten_bytecode


def test_every_collected_test_module_and_conftest_is_listed():
    listed = set(modules_pytest_rewrites())
    assert Path(__file__) in listed
    assert ROOT / "tests" / "conftest.py" in listed
    assert all(p.name.startswith("test_") or p.name == "conftest.py" for p in listed)


def test_the_written_bytecode_is_pytests_rewrite_and_pytest_reads_it(tmp_path: Path):
    module = tmp_path / "test_planted.py"
    module.write_text("def test_x():\n    a = 1\n    assert a + 1 == 3, 'off'\n")
    assert write_rewritten_bytecode([module]) == 1
    pyc = rewrite.get_cache_dir(module) / ("test_planted" + rewrite.PYC_TAIL)
    read = rewrite._read_pyc(module, pyc)
    assert read is not None  # pytest's reader accepts it (hash-checked against the source)
    assert read == rewrite._rewrite_test(module, None)[1]  # type: ignore[arg-type]
    function = next(c for c in read.co_consts if hasattr(c, "co_varnames"))
    assert any(name.startswith("@py_assert") for name in function.co_varnames)  # the assert was rewritten
    assert marshal.loads(pyc.read_bytes()[16:]) == read
