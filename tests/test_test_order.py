"""The order xdist hands the tests out in (tests/conftest.py:long_tests_first)."""

from __future__ import annotations

from dataclasses import dataclass

from tests.conftest import long_tests_first


@dataclass
class Marked:
    """What long_tests_first reads of a test: its name and marks."""

    name: str
    marks: tuple[str, ...]

    def get_closest_marker(self, name: str) -> object | None:
        return name if name in self.marks else None


def test_long_tests_come_first_with_the_waiting_ones_spread_among_the_computing_ones() -> None:
    items = [
        Marked("quick0", ()),
        Marked("int0", ("integration",)),
        Marked("int1", ("integration", "slow")),
        Marked("browser0", ("browser",)),
        Marked("quick1", ()),
        Marked("core0", ("slow",)),
        Marked("core1", ("slow",)),
        Marked("core2", ("slow",)),
        Marked("quick2", ()),
    ]
    order = [item.name for item in long_tests_first(items)]  # type: ignore[arg-type]
    # waiting at 1/6, 3/6, 5/6; computing at 1/6, 3/6, 5/6: ties keep collection order
    assert order == ["int0", "core0", "int1", "core1", "browser0", "core2", "quick0", "quick1", "quick2"]


def test_without_long_tests_the_order_is_the_collections() -> None:
    items = [Marked(f"t{k}", ()) for k in range(5)]
    assert [item.name for item in long_tests_first(items)] == [f"t{k}" for k in range(5)]  # type: ignore[arg-type]
