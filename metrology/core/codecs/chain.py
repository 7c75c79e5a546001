"""The grammar of an unwrapping chain's stage labels, beats of beats included.

A stage label is ``gray``, ``phase:I`` or ``beat:X,Y``, where X and Y are each an operand::

    operand := I | "(" operand "," operand ")"

``I`` is an index into the axis's phase sequences and a parenthesised pair is the beat of its
two operands, to any depth: ``beat:(0,1),(1,2)`` is the beat of the beats ``(0,1)`` and
``(1,2)`` (three-frequency heterodyne), ``beat:0,1`` the beat of sequences 0 and 1. Spaces are
ignored. :func:`parse_stage_label` turns a label into a tree of :class:`Operand`; the codec
model gives each node its period and origin by the beat rule (``metrology.core.codecs.model``).
"""

from __future__ import annotations

from dataclasses import dataclass


class ChainSyntaxError(ValueError):
    """A stage label does not follow the grammar; the message says where."""


@dataclass(frozen=True)
class Operand:
    """A node of a stage's tree: a phase sequence (``index``) or the beat of ``parts`` (two operands)."""

    index: int | None = None
    parts: tuple[Operand, ...] = ()

    @property
    def text(self) -> str:
        """The canonical operand text: ``I`` or ``(X,Y)``."""
        if self.index is not None:
            return str(self.index)
        return f"({self.parts[0].text},{self.parts[1].text})"

    def leaves(self) -> tuple[int, ...]:
        """Phase indices of the tree, left to right, repeats kept."""
        if self.index is not None:
            return (self.index,)
        return self.parts[0].leaves() + self.parts[1].leaves()


@dataclass(frozen=True)
class StageLabel:
    """A parsed stage label: ``kind`` in gray, phase, beat; ``tree`` the phase index or the beat."""

    kind: str
    tree: Operand | None

    @property
    def text(self) -> str:
        """The canonical label (``gray``, ``phase:I``, ``beat:X,Y`` without spaces)."""
        if self.tree is None:
            return "gray"
        if self.kind == "phase":
            return f"phase:{self.tree.text}"
        return f"beat:{self.tree.parts[0].text},{self.tree.parts[1].text}"


def parse_stage_label(label: str) -> StageLabel:
    """Parse a chain entry (``gray``, ``phase:I``, ``beat:X,Y``; X, Y an index or a ``(X,Y)`` pair).

    Raises
    ------
    ChainSyntaxError
        Saying what was expected and where.
    """
    text = "".join(label.split())
    if text == "gray":
        return StageLabel("gray", None)
    kind, colon, rest = text.partition(":")
    if not colon or kind not in ("phase", "beat"):
        raise ChainSyntaxError("expected 'gray', 'phase:I' or 'beat:X,Y'")
    if kind == "phase":
        if not rest.isdigit():
            raise ChainSyntaxError("'phase:' takes one phase index, e.g. 'phase:0'")
        return StageLabel("phase", Operand(index=int(rest)))
    # a beat is the pair "X,Y" without its parentheses
    tree, end = _operand(f"({rest})", 0)
    if end != len(rest) + 2 or tree.index is not None:
        raise ChainSyntaxError("'beat:' takes two operands X,Y, each a phase index or a pair (X,Y)")
    return StageLabel("beat", tree)


def _operand(text: str, pos: int) -> tuple[Operand, int]:
    """The operand starting at ``pos`` and the position after it (recursive descent)."""
    if pos < len(text) and text[pos].isdigit():
        end = pos
        while end < len(text) and text[end].isdigit():
            end += 1
        return Operand(index=int(text[pos:end])), end
    if pos >= len(text) or text[pos] != "(":
        raise ChainSyntaxError(f"expected a phase index or '(' at character {pos}")
    first, pos = _operand(text, pos + 1)
    if pos >= len(text) or text[pos] != ",":
        raise ChainSyntaxError(f"expected ',' at character {pos}")
    second, pos = _operand(text, pos + 1)
    if pos >= len(text) or text[pos] != ")":
        raise ChainSyntaxError(f"expected ')' at character {pos}")
    return Operand(parts=(first, second)), pos + 1
