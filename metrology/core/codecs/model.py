"""The codec model (gcps-codec/1): a pattern sequence described as data.

A codec says which camera frame shows which pattern and how the frames decode to absolute
projector coordinates, per coded axis: ``u`` (projector columns) and ``v`` (projector rows).
Coordinates are in projector units: ``x = j`` is the centre of projector column (or row) ``j``
and a projector pixel spans ``[j - 0.5, j + 0.5)``, as in OpenCV. docs/codecs.md describes the
JSON format; this module holds its dataclasses, their validation (every bad field is named),
JSON reading and writing, the natural order of frame files, and the built-in ``gcps-v1``.

Phase sequence (N >= 3 frames): frame k shows
``I_k = A + B cos(2 pi (x - origin) / period + 2 pi shift k / N)``.
Gray code (``bits`` frames): word n (reflected gray code ``g = n ^ (n >> 1)``; with ``levels``
L > 2 its base-L reflected gray digits, shown as grey levels ``d / (L - 1)``) covers
``[origin + n word, origin + (n + 1) word)``.
"""

from __future__ import annotations

import functools
import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from metrology.core.codecs.chain import ChainSyntaxError, Operand, parse_stage_label

CODEC_FORMAT = "gcps-codec/1"
"""Value of the ``codec`` key of every codec file."""

AXES: tuple[str, ...] = ("u", "v")
"""Coded axes: ``u`` = projector columns (x), ``v`` = projector rows (y)."""

WAVEFORMS: tuple[str, ...] = ("sine", "square")
GRAY_ORDERS: tuple[str, ...] = ("msb_first", "lsb_first")
MAX_GRAY_BITS = 16
"""Largest number of gray-code bits of one axis (65536 words)."""
MIN_GRAY_LEVELS, MAX_GRAY_LEVELS = 2, 8
"""Accepted ``levels`` of a gray code (2: binary, the default)."""
MAX_GRAY_WORDS = 65536
"""Largest ``levels ** digits`` of a gray code."""
MAX_PROJECTOR_SIDE = 16384
"""Largest projector width or height, pixels (a codec describing a larger one is refused)."""
MAX_EXTENTS_PER_LENGTH = 64
"""Largest phase period or gray word, in multiples of the projector's extent along the axis
(longer ones code nothing a real stack could show, and overflow the decoders' arithmetic)."""
PRECOMPENSATED_GAMMA_RANGE: tuple[float, float] = (0.2, 5.0)
"""Accepted ``precompensated_gamma`` values (inclusive)."""

MAX_CODEC_DEPTH = 16
"""Deepest nesting of arrays and objects in a codec file (a codec needs 5; deeper is refused, not
parsed into a ``RecursionError``)."""

COVER_TOLERANCE = 1e-9
"""A first stage without a gray code covers the projector when its period is at least
``extent * (1 - COVER_TOLERANCE)`` (a beat of beats of periods W/64, W/58, W/53 has period W up
to rounding)."""

GCPS_V1 = "gcps-v1"
"""Name of the built-in codec of the paper's eleven patterns (:func:`gcps_v1_codec`)."""
BUILTIN_NAMES: tuple[str, ...] = (GCPS_V1,)
"""Names accepted by :func:`builtin_codec` (``gcps-v1`` or ``gcps-v1:WIDTHxHEIGHT``)."""


class CodecError(ValueError):
    """A codec is malformed; the one-line message names the field and the problem."""


@dataclass(frozen=True)
class PhaseSequence:
    """One N-step phase-shift sequence along an axis.

    Attributes
    ----------
    frames : tuple of int
        Frame indices, in shift order k = 0 .. N-1; N >= 3.
    period : float
        Fringe period, projector units, > 0.
    shift : {+1, -1}
        Sign of the phase step ``2 pi shift k / N``.
    origin : float
        Projector coordinate where the phase ``theta = 2 pi (x - origin) / period`` is 0.
    waveform : {"sine", "square"}
        Square is a 50 % duty square wave, 1 where the cosine is >= 0.
    """

    frames: tuple[int, ...]
    period: float
    shift: int = 1
    origin: float = 0.0
    waveform: str = "sine"

    @property
    def steps(self) -> int:
        """N, the number of frames."""
        return len(self.frames)


@dataclass(frozen=True)
class GrayCode:
    """A reflected binary gray code along an axis.

    Attributes
    ----------
    frames : tuple of int
        One frame per bit, in projection order (``order`` says which bit comes first).
    word : float
        Width of one code word, projector units, > 0.
    order : {"msb_first", "lsb_first"}
    origin : float
        Left (top) edge of word 0; an OpenCV-style single-pixel code (word 1) has origin -0.5.
    inverse_frames : tuple of int or None
        Each bit's inverse image (same length as ``frames``): the bit's threshold.
    inverted : bool
        Flip every bit after thresholding.
    levels : int
        L, 2 (binary, the default) to 8: each frame shows one base-L digit of the word's
        reflected gray code as the grey level ``d / (L - 1)`` (``metrology.core.codecs.gray``);
        ``inverse_frames`` and ``inverted`` apply to L = 2 only; ``L**bits <= 65536``.
    """

    frames: tuple[int, ...]
    word: float
    order: str = "msb_first"
    origin: float = 0.0
    inverse_frames: tuple[int, ...] | None = None
    inverted: bool = False
    levels: int = 2

    @property
    def bits(self) -> int:
        """Number of bit (digit) frames."""
        return len(self.frames)

    @property
    def words(self) -> int:
        """Number of code words, ``levels ** bits``."""
        return int(self.levels) ** self.bits

    def centre(self, n: int) -> float:
        """Projector coordinate of the centre of word ``n``: ``origin + (n + 0.5) word``."""
        return self.origin + (n + 0.5) * self.word


@dataclass(frozen=True)
class Stage:
    """One stage of an unwrapping chain.

    ``kind`` is ``"gray"``, ``"phase"`` (``indices = (i,)``) or ``"beat"``. A beat has ``parts``,
    its two operands as stages (each a phase or a beat: beats of beats nest to any depth), and
    ``indices``, the phase sequences it reads (for ``beat:i,j``: ``(i, j)``). ``period`` and
    ``origin`` are the stage's (for a beat of operands s, the shorter period, and l, the longer:
    ``P_b = P_s P_l / (P_l - P_s)``, ``o_b = P_b (o_s / P_s - o_l / P_l)``); a gray stage has
    period 0.
    """

    kind: str
    indices: tuple[int, ...]
    period: float
    origin: float
    parts: tuple[Stage, ...] = ()

    @property
    def label(self) -> str:
        """The chain entry: ``gray``, ``phase:I`` or ``beat:X,Y`` (X, Y an index or a ``(X,Y)`` pair)."""
        if self.kind == "gray":
            return "gray"
        if self.kind == "phase":
            return f"phase:{self.indices[0]}"
        return f"beat:{self.parts[0].operand},{self.parts[1].operand}"

    @property
    def operand(self) -> str:
        """The stage as an operand of a beat: ``I`` for a phase, ``(X,Y)`` for a beat."""
        if self.kind == "phase":
            return str(self.indices[0])
        return f"({self.parts[0].operand},{self.parts[1].operand})"

    def ordered_parts(self) -> tuple[Stage, Stage]:
        """A beat's operands as (shorter period, longer period)."""
        a, b = self.parts
        return (a, b) if a.period < b.period else (b, a)

    def phase_weights(self) -> dict[int, int]:
        """Integer weights ``w_i`` with ``theta = sum_i w_i theta_i (mod 2 pi)`` over the phase sequences.

        A phase stage is ``{i: 1}``; a beat ``theta_s - theta_l`` (s the operand of the shorter
        period), e.g. ``beat:(0,1),(1,2)`` with periods falling from 0 to 2 is
        ``theta_0 - 2 theta_1 + theta_2``. Its phase variance is ``sum_i w_i^2 var(theta_i)``.
        """
        if self.kind == "phase":
            return {self.indices[0]: 1}
        if self.kind == "gray":
            return {}
        short, long_ = self.ordered_parts()
        weights = dict(short.phase_weights())
        for i, w in long_.phase_weights().items():
            weights[i] = weights.get(i, 0) - w
        return {i: w for i, w in weights.items() if w != 0}


@dataclass(frozen=True)
class Axis:
    """How one projector axis is coded.

    Attributes
    ----------
    phase : tuple of PhaseSequence
        Zero or more phase sequences.
    gray : GrayCode or None
    unwrap : tuple of str or None
        Explicit chain (``"gray"``, ``"phase:i"``, ``"beat:i,j"``), coarse to fine; None for
        the default chain (gray, then the phase sequences from the longest period to the shortest).
    """

    phase: tuple[PhaseSequence, ...] = ()
    gray: GrayCode | None = None
    unwrap: tuple[str, ...] | None = None

    def chain(self) -> tuple[Stage, ...]:
        """The unwrapping chain as stages (the explicit ``unwrap`` or the default one)."""
        if self.unwrap is None:
            labels: list[str] = ["gray"] if self.gray is not None else []
            order = sorted(range(len(self.phase)), key=lambda i: -self.phase[i].period)
            labels += [f"phase:{i}" for i in order]
        else:
            labels = list(self.unwrap)
        return tuple(_parse_stage(label, self.phase) for label in labels)


@dataclass(frozen=True)
class Codec:
    """A complete pattern sequence (gcps-codec/1).

    Attributes
    ----------
    frames : int or tuple of str
        Number of frames (files taken in natural order, optionally filtered by ``files``) or
        the frame file names in frame order.
    projector_width, projector_height : int
        Projector size, projector units (pixels).
    axes : mapping of str to Axis
        Coded axes, keys among ``"u"``, ``"v"``.
    white, black : tuple of int
        Frames of full white and full black (averaged when several).
    files : str or None
        Glob selecting the frame files when ``frames`` is a number (e.g. ``"pat*.png"``).
    precompensated_gamma : float or None
        The projector gamma ``g`` (0.2..5) the generated patterns are pre-compensated for: a
        pattern value ``s`` in 0..1 is written as ``s**(1/g)``, so a projector emitting
        ``value**g`` emits ``s``. None: patterns are written linearly.
    name : str or None
        Name of a built-in codec (not part of the file format).
    """

    frames: int | tuple[str, ...]
    projector_width: int
    projector_height: int
    axes: Mapping[str, Axis]
    white: tuple[int, ...] = ()
    black: tuple[int, ...] = ()
    files: str | None = None
    precompensated_gamma: float | None = None
    name: str | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        validate_codec(self)

    @property
    def n_frames(self) -> int:
        """Number of frames of a matching stack."""
        return self.frames if isinstance(self.frames, int) else len(self.frames)

    def extent(self, axis: str) -> int:
        """Projector size along ``axis``: width for u, height for v."""
        return self.projector_width if axis == "u" else self.projector_height

    def light_codes(self, u: Any, nlp: int) -> Any:
        """The paper's light codes of projector columns ``u``: ``l = (u + 0.5) nlp / width``.

        For a crossed-axes rig whose coded field spans the projector's width with ``nlp`` codes.
        ``u``: array (or float) of projector column coordinates; returns the same shape.
        """
        return (u + 0.5) * (nlp / self.projector_width)

    def to_dict(self) -> dict[str, Any]:
        """The JSON-ready dict of the codec file (gcps-codec/1)."""
        out: dict[str, Any] = {"codec": CODEC_FORMAT}
        out["frames"] = self.frames if isinstance(self.frames, int) else list(self.frames)
        if self.files is not None:
            out["files"] = self.files
        out["projector"] = {"width": self.projector_width, "height": self.projector_height}
        if self.precompensated_gamma is not None:
            out["precompensated_gamma"] = self.precompensated_gamma
        if self.white:
            out["white"] = list(self.white)
        if self.black:
            out["black"] = list(self.black)
        axes: dict[str, Any] = {}
        for name in AXES:
            if name not in self.axes:
                continue
            axis = self.axes[name]
            entry: dict[str, Any] = {}
            if axis.phase:
                entry["phase"] = [
                    {
                        "frames": list(p.frames),
                        "period": p.period,
                        "shift": p.shift,
                        "origin": p.origin,
                        "waveform": p.waveform,
                    }
                    for p in axis.phase
                ]
            if axis.gray is not None:
                g = axis.gray
                entry["gray"] = {
                    "frames": list(g.frames),
                    "order": g.order,
                    "word": g.word,
                    "origin": g.origin,
                    "inverse_frames": None if g.inverse_frames is None else list(g.inverse_frames),
                    "inverted": g.inverted,
                }
                if g.levels != 2:
                    entry["gray"]["levels"] = g.levels
            if axis.unwrap is not None:
                entry["unwrap"] = list(axis.unwrap)
            axes[name] = entry
        out["axes"] = axes
        return out

    def to_json(self) -> str:
        """The codec file's text (indented JSON, trailing newline)."""
        return json.dumps(self.to_dict(), indent=1) + "\n"


# ----------------------------------------------------------------------------- parsing
def _parse_stage(label: str, phase: Sequence[PhaseSequence]) -> Stage:
    """A chain entry as a :class:`Stage` (indices already validated by :func:`validate_codec`)."""
    parsed = parse_stage_label(label)
    if parsed.tree is None:
        return Stage("gray", (), 0.0, 0.0)
    return _operand_stage(parsed.tree, phase)


def _operand_stage(tree: Operand, phase: Sequence[PhaseSequence]) -> Stage:
    """The stage of a parsed operand: a phase sequence, or the beat of two operands (recursively)."""
    if tree.index is not None:
        p = phase[tree.index]
        return Stage("phase", (tree.index,), p.period, p.origin)
    a, b = (_operand_stage(part, phase) for part in tree.parts)
    short, long_ = (a, b) if a.period < b.period else (b, a)
    if long_.period == short.period:  # refused by validation: a beat needs two different periods
        return Stage("beat", tuple(dict.fromkeys(tree.leaves())), math.inf, 0.0, parts=(a, b))
    period = short.period * long_.period / (long_.period - short.period)
    origin = period * (short.origin / short.period - long_.origin / long_.period)
    indices = tuple(dict.fromkeys(tree.leaves()))
    return Stage("beat", indices, period, origin, parts=(a, b))


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_real(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _check_keys(where: str, data: Any, allowed: Sequence[str], required: Sequence[str]) -> None:
    if not isinstance(data, Mapping):
        raise CodecError(f"codec field {where} must be an object, got {type(data).__name__}")
    unknown = [key for key in data if key not in allowed]
    if unknown:
        raise CodecError(f"codec field {where} has unknown key {unknown[0]!r}; allowed keys: {', '.join(allowed)}")
    missing = [key for key in required if key not in data]
    if missing:
        raise CodecError(f"codec field {where} is missing the required key {missing[0]!r}")


def _int_list(where: str, value: Any, *, min_length: int = 0) -> tuple[int, ...]:
    if not isinstance(value, list) or not all(_is_int(v) for v in value):
        raise CodecError(f"codec field {where} must be a list of frame indices (integers), got {value!r}")
    if len(value) < min_length:
        raise CodecError(f"codec field {where} must hold at least {min_length} frame(s), got {len(value)}")
    return tuple(int(v) for v in value)


def _real(where: str, value: Any) -> float:
    if not _is_real(value):
        raise CodecError(f"codec field {where} must be a finite number, got {value!r}")
    return float(value)


def _phase_from_dict(where: str, data: Any) -> PhaseSequence:
    _check_keys(where, data, ("frames", "period", "shift", "origin", "waveform"), ("frames", "period"))
    frames = _int_list(f"{where}.frames", data["frames"])
    period = _real(f"{where}.period", data["period"])
    shift = data.get("shift", 1)
    origin = _real(f"{where}.origin", data.get("origin", 0.0))
    waveform = data.get("waveform", "sine")
    return PhaseSequence(frames=frames, period=period, shift=shift, origin=origin, waveform=waveform)


def _gray_from_dict(where: str, data: Any) -> GrayCode:
    _check_keys(
        where, data, ("frames", "order", "word", "origin", "inverse_frames", "inverted", "levels"), ("frames", "word")
    )
    frames = _int_list(f"{where}.frames", data["frames"])
    word = _real(f"{where}.word", data["word"])
    origin = _real(f"{where}.origin", data.get("origin", 0.0))
    inverse = data.get("inverse_frames")
    inverse_frames = None if inverse is None else _int_list(f"{where}.inverse_frames", inverse)
    return GrayCode(
        frames=frames,
        word=word,
        order=data.get("order", "msb_first"),
        origin=origin,
        inverse_frames=inverse_frames,
        inverted=data.get("inverted", False),
        levels=data.get("levels", 2),
    )


def codec_from_dict(data: Any) -> Codec:
    """Build and validate a :class:`Codec` from the parsed JSON of a codec file.

    Raises
    ------
    CodecError
        Naming the first bad field (unknown key, wrong type, value out of range, frame index
        out of range, overlapping frame use, bad unwrap chain, missing threshold source...).
    """
    _check_keys(
        "(top level)",
        data,
        ("codec", "frames", "files", "projector", "white", "black", "axes", "precompensated_gamma"),
        ("codec", "frames", "projector", "axes"),
    )
    if data["codec"] != CODEC_FORMAT:
        raise CodecError(f"codec field codec must be {CODEC_FORMAT!r}, got {data['codec']!r}")
    frames_value = data["frames"]
    frames: int | tuple[str, ...]
    if _is_int(frames_value):
        frames = int(frames_value)
    elif isinstance(frames_value, list) and all(isinstance(f, str) for f in frames_value):
        frames = tuple(frames_value)
    else:
        raise CodecError(f"codec field frames must be a number of frames or a list of file names, got {frames_value!r}")
    files = data.get("files")
    if files is not None and not isinstance(files, str):
        raise CodecError(f"codec field files must be a glob string such as 'pat*.png', got {files!r}")
    projector = data["projector"]
    _check_keys("projector", projector, ("width", "height"), ("width", "height"))
    width, height = projector["width"], projector["height"]
    for key, value in (("width", width), ("height", height)):
        if not _is_int(value) or value <= 0:
            raise CodecError(f"codec field projector.{key} must be a positive integer, got {value!r}")
    white = _int_list("white", data.get("white", []))
    black = _int_list("black", data.get("black", []))
    gamma_value = data.get("precompensated_gamma")
    if gamma_value is not None and not _is_real(gamma_value):
        raise CodecError(
            f"codec field precompensated_gamma must be a number (the projector gamma), got {gamma_value!r}"
        )
    axes_data = data["axes"]
    _check_keys("axes", axes_data, AXES, ())
    axes: dict[str, Axis] = {}
    for name, axis_data in axes_data.items():
        where = f"axes.{name}"
        _check_keys(where, axis_data, ("phase", "gray", "unwrap"), ())
        phase_data = axis_data.get("phase", [])
        if not isinstance(phase_data, list):
            raise CodecError(f"codec field {where}.phase must be a list of phase sequences, got {phase_data!r}")
        phase = tuple(_phase_from_dict(f"{where}.phase[{i}]", p) for i, p in enumerate(phase_data))
        gray_data = axis_data.get("gray")
        gray = None if gray_data is None else _gray_from_dict(f"{where}.gray", gray_data)
        unwrap = axis_data.get("unwrap")
        if unwrap is not None:
            if not isinstance(unwrap, list) or not all(isinstance(s, str) for s in unwrap):
                raise CodecError(f"codec field {where}.unwrap must be a list of strings, got {unwrap!r}")
            unwrap = tuple(unwrap)
        axes[name] = Axis(phase=phase, gray=gray, unwrap=unwrap)
    return Codec(
        frames=frames,
        projector_width=int(width),
        projector_height=int(height),
        axes=axes,
        white=white,
        black=black,
        files=files,
        precompensated_gamma=None if gamma_value is None else float(gamma_value),
    )


def codec_from_json(text: str | bytes, label: str = "codec") -> Codec:
    """Parse and validate the text of a codec file.

    Raises
    ------
    CodecError
        If the text is not JSON (naming ``label``), is nested deeper than :data:`MAX_CODEC_DEPTH`
        levels, or the codec is invalid.
    """
    try:
        data = json.loads(text)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CodecError(f"{label} is not valid JSON ({exc})") from None
    except RecursionError:
        raise CodecError(f"{label} is nested deeper than {MAX_CODEC_DEPTH} levels") from None
    if _nesting_depth(data) > MAX_CODEC_DEPTH:
        raise CodecError(f"{label} is nested deeper than {MAX_CODEC_DEPTH} levels")
    return codec_from_dict(data)


def _nesting_depth(value: Any) -> int:
    """Deepest nesting of lists and dicts in a parsed JSON ``value`` (iterative: any depth)."""
    deepest = 0
    stack: list[tuple[Any, int]] = [(value, 0)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict | list):
            deepest = max(deepest, depth + 1)
            stack.extend((child, depth + 1) for child in (item.values() if isinstance(item, dict) else item))
    return deepest


def read_codec(path: str | Path) -> Codec:
    """Read a codec file, or resolve a built-in name (``gcps-v1``, ``gcps-v1:WIDTHxHEIGHT``).

    Raises
    ------
    CodecError
        If the file does not exist, is not JSON, or the codec is invalid.
    """
    text = str(path)
    if text.split(":", 1)[0] in BUILTIN_NAMES and not Path(text).exists():
        return builtin_codec(text)
    p = Path(path)
    if not p.is_file():
        raise CodecError(f"codec {text}: no such file (nor a built-in codec: {', '.join(BUILTIN_NAMES)})")
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise CodecError(f"codec {text}: cannot read ({exc.strerror or exc})") from None
    return codec_from_json(raw, label=f"codec {p.name}")


def write_codec(codec: Codec, path: str | Path) -> None:
    """Write ``codec`` as a codec file (atomic: temporary file, then rename)."""
    from metrology.core.io import write_text_atomic

    write_text_atomic(codec.to_json(), path)


# ----------------------------------------------------------------------------- validation
def validate_codec(codec: Codec) -> None:
    """Check every field of ``codec`` and their consistency.

    Raises
    ------
    CodecError
        Naming the field: projector sides above 16384 px, N < 3, period <= 0, not finite or
        above 64 times the projector's extent, shift not +-1, unknown waveform or order, word
        <= 0, not finite or above 64 times the extent, more than 16 gray bits, gray levels
        outside 2..8 or ``levels ** digits`` above 65536, inverse frames or ``inverted`` with
        levels > 2, inverse list of the wrong length, frame index out of range, a frame used
        twice, a gray code with no threshold source, a bad unwrap chain (a gray word wider than
        the period of the stage it unwraps), an axis with nothing coded, a first stage that does
        not cover the projector, no axis at all.
    """
    if codec.precompensated_gamma is not None:
        pg = codec.precompensated_gamma
        lo, hi = PRECOMPENSATED_GAMMA_RANGE
        if not (isinstance(pg, (int, float)) and math.isfinite(pg) and lo <= pg <= hi):
            raise CodecError(f"codec field precompensated_gamma must be a number in {lo:g}..{hi:g}, got {pg!r}")
    if isinstance(codec.frames, int):
        if codec.frames < 1:
            raise CodecError(f"codec field frames must be a positive number, got {codec.frames}")
    else:
        if not codec.frames:
            raise CodecError("codec field frames must not be an empty list")
        for i, name in enumerate(codec.frames):
            if not name or "/" in name or "\\" in name:
                raise CodecError(f"codec field frames[{i}] must be a plain file name, got {name!r}")
        seen: dict[str, int] = {}
        for i, name in enumerate(codec.frames):
            if name in seen:
                raise CodecError(f"codec field frames lists {name!r} twice (frames[{seen[name]}] and frames[{i}])")
            seen[name] = i
        if codec.files is not None:
            raise CodecError("codec field files applies only when frames is a number, not a list of names")
    if codec.files is not None and not codec.files:
        raise CodecError("codec field files must not be empty")
    for key, value in (("projector.width", codec.projector_width), ("projector.height", codec.projector_height)):
        if not _is_int(value) or value <= 0:
            raise CodecError(f"codec field {key} must be a positive integer, got {value!r}")
        if value > MAX_PROJECTOR_SIDE:
            raise CodecError(f"codec field {key} must be at most {MAX_PROJECTOR_SIDE} pixels, got {value!r}")
    if not codec.axes:
        raise CodecError("codec field axes must code at least one axis (u or v)")
    n = codec.n_frames
    users: dict[int, str] = {}

    def use(where: str, frames: Sequence[int]) -> None:
        for k, f in enumerate(frames):
            if not 0 <= f < n:
                raise CodecError(f"codec field {where}[{k}] = {f} is out of range: frames are 0..{n - 1}")
            if f in users:
                raise CodecError(f"codec field {where}[{k}] uses frame {f}, already used by {users[f]}")
            users[f] = f"{where}[{k}]"

    use("white", codec.white)
    use("black", codec.black)
    for name, axis in codec.axes.items():
        where = f"axes.{name}"
        if name not in AXES:
            raise CodecError(f"codec field axes has unknown axis {name!r}; axes are u and v")
        if not axis.phase and axis.gray is None:
            raise CodecError(f"codec field {where} codes nothing: give phase and/or gray")
        for i, p in enumerate(axis.phase):
            pw = f"{where}.phase[{i}]"
            if len(p.frames) < 3:
                raise CodecError(f"codec field {pw}.frames must hold N >= 3 frames, got N = {len(p.frames)}")
            if not _is_real(p.period):
                raise CodecError(f"codec field {pw}.period must be a finite number, got {p.period!r}")
            if p.period <= 0:
                raise CodecError(f"codec field {pw}.period must be > 0, got {p.period!r}")
            _check_length(f"{pw}.period", p.period, codec.extent(name))
            if not _is_int(p.shift) or p.shift not in (1, -1):
                raise CodecError(f"codec field {pw}.shift must be 1 or -1, got {p.shift!r}")
            if not _is_real(p.origin):
                raise CodecError(f"codec field {pw}.origin must be a finite number, got {p.origin!r}")
            if p.waveform not in WAVEFORMS:
                raise CodecError(f"codec field {pw}.waveform must be one of {', '.join(WAVEFORMS)}, got {p.waveform!r}")
            use(f"{pw}.frames", p.frames)
        g = axis.gray
        if g is not None:
            gw = f"{where}.gray"
            if not _is_int(g.levels) or not MIN_GRAY_LEVELS <= g.levels <= MAX_GRAY_LEVELS:
                raise CodecError(
                    f"codec field {gw}.levels must be an integer from {MIN_GRAY_LEVELS} to {MAX_GRAY_LEVELS}, "
                    f"got {g.levels!r}"
                )
            if not 1 <= len(g.frames) <= MAX_GRAY_BITS:
                raise CodecError(f"codec field {gw}.frames must hold 1..{MAX_GRAY_BITS} bits, got {len(g.frames)}")
            if g.words > MAX_GRAY_WORDS:
                raise CodecError(
                    f"codec field {gw}.frames: {len(g.frames)} digits of {g.levels} levels make {g.words} words; "
                    f"levels ** digits must be at most {MAX_GRAY_WORDS}"
                )
            if g.levels != 2 and g.inverse_frames is not None:
                raise CodecError(f"codec field {gw}.inverse_frames applies to levels = 2 only, not {g.levels}")
            if g.levels != 2 and g.inverted is not False:
                raise CodecError(f"codec field {gw}.inverted applies to levels = 2 only, not {g.levels}")
            if not _is_real(g.word):
                raise CodecError(f"codec field {gw}.word must be a finite number, got {g.word!r}")
            if g.word <= 0:
                raise CodecError(f"codec field {gw}.word must be > 0, got {g.word!r}")
            _check_length(f"{gw}.word", g.word, codec.extent(name))
            if not _is_real(g.origin):
                raise CodecError(f"codec field {gw}.origin must be a finite number, got {g.origin!r}")
            if g.order not in GRAY_ORDERS:
                raise CodecError(f"codec field {gw}.order must be one of {', '.join(GRAY_ORDERS)}, got {g.order!r}")
            if not isinstance(g.inverted, bool):
                raise CodecError(f"codec field {gw}.inverted must be true or false, got {g.inverted!r}")
            use(f"{gw}.frames", g.frames)
            if g.inverse_frames is not None:
                if len(g.inverse_frames) != len(g.frames):
                    raise CodecError(
                        f"codec field {gw}.inverse_frames must hold one frame per bit ({len(g.frames)}), "
                        f"got {len(g.inverse_frames)}"
                    )
                use(f"{gw}.inverse_frames", g.inverse_frames)
            elif not (codec.white and codec.black) and not axis.phase:
                raise CodecError(
                    f"codec field {gw} has no threshold source: give inverse_frames, white and black frames, "
                    "or a phase sequence on the axis"
                )
        _validate_chain(where, axis, codec.extent(name))


def _check_length(where: str, value: float, extent: int) -> None:
    """Refuse a period or word longer than :data:`MAX_EXTENTS_PER_LENGTH` times the axis' ``extent``."""
    limit = MAX_EXTENTS_PER_LENGTH * extent
    if value > limit:
        raise CodecError(
            f"codec field {where} must be at most {MAX_EXTENTS_PER_LENGTH} times the projector's extent "
            f"along the axis ({MAX_EXTENTS_PER_LENGTH} x {extent} = {limit} px), got {value!r}"
        )


def _validate_chain(where: str, axis: Axis, extent: int) -> None:
    labels = list(axis.unwrap) if axis.unwrap is not None else None
    if labels is not None:
        if not labels:
            raise CodecError(f"codec field {where}.unwrap must not be empty")
        canonical: list[str] = []
        for k, label in enumerate(labels):
            try:
                parsed = parse_stage_label(label) if isinstance(label, str) else None
            except ChainSyntaxError as exc:
                raise CodecError(
                    f"codec field {where}.unwrap[{k}] = {label!r} is not 'gray', 'phase:I' or 'beat:I,J' "
                    f"(I, J a phase index or a pair such as (0,1)): {exc}"
                ) from None
            if parsed is None:
                raise CodecError(f"codec field {where}.unwrap[{k}] = {label!r} is not 'gray', 'phase:I' or 'beat:I,J'")
            canonical.append(parsed.text)
            if parsed.tree is None:
                if axis.gray is None:
                    raise CodecError(f"codec field {where}.unwrap[{k}] is 'gray' but the axis has no gray code")
                if k != 0:
                    raise CodecError(f"codec field {where}.unwrap[{k}]: 'gray' can only be the first stage")
                continue
            for i in parsed.tree.leaves():
                if i >= len(axis.phase):
                    raise CodecError(
                        f"codec field {where}.unwrap[{k}] = {label!r}: the axis has {len(axis.phase)} phase sequence(s)"
                    )
            for beat in _beats(_operand_stage(parsed.tree, axis.phase)):
                a, b = beat.parts
                if a.period == b.period:
                    raise CodecError(
                        f"codec field {where}.unwrap[{k}] = {label!r}: a beat needs two different periods "
                        f"({beat.operand} beats {a.operand} with {b.operand}, both of period {a.period:g})"
                    )
        if len(set(canonical)) != len(canonical):
            raise CodecError(f"codec field {where}.unwrap repeats a stage: {labels}")
    chain = axis.chain()
    previous: Stage | None = None
    for stage in chain:
        if stage.kind == "gray":
            previous = stage
            continue
        if previous is None and stage.period < extent * (1 - COVER_TOLERANCE):
            raise CodecError(
                f"codec field {where}: the first unwrapping stage {stage.label} has period {stage.period:g}, "
                f"shorter than the projector's {extent} px, and there is no gray code to unwrap it"
            )
        if previous is not None and previous.kind == "gray" and axis.gray is not None and axis.gray.word > stage.period:
            # the stage unwraps within +-P/2 of the word's centre: a wider word leaves whole periods undecided
            raise CodecError(
                f"codec field {where}: the gray word ({axis.gray.word:g}) is wider than the period "
                f"{stage.period:g} of {stage.label}, the stage it unwraps, which cannot tell the periods "
                "in one word apart (a word at most as wide as that period is needed)"
            )
        if previous is not None and previous.kind != "gray" and stage.period >= previous.period:
            raise CodecError(
                f"codec field {where}: unwrapping stage {stage.label} (period {stage.period:g}) must have a shorter "
                f"period than the stage before it, {previous.label} (period {previous.period:g})"
            )
        previous = stage
    if not chain:
        raise CodecError(f"codec field {where} has an empty unwrapping chain")


def _beats(stage: Stage) -> list[Stage]:
    """Every beat of a stage's tree (the stage itself included), outermost first."""
    if stage.kind != "beat":
        return []
    return [stage, *_beats(stage.parts[0]), *_beats(stage.parts[1])]


# ----------------------------------------------------------------------------- frame files
_RUNS = re.compile(r"(\d+)")


def natural_key(name: str) -> tuple[tuple[tuple[int, int, str], ...], str]:
    """Sort key of the natural order: digit runs as integers, text case-folded, ties on the raw name.

    >>> sorted(["10.bmp", "2.bmp", "01.bmp", "00.Bmp"], key=natural_key)
    ['00.Bmp', '01.bmp', '2.bmp', '10.bmp']
    """
    runs = tuple((0, int(run), "") if run.isdigit() else (1, 0, run.casefold()) for run in _RUNS.split(name) if run)
    return runs, name


# ----------------------------------------------------------------------------- built-in codecs
def gcps_v1_codec(width: int = 1024, height: int = 768, nlp: int = 128) -> Codec:
    """The paper's eleven patterns GC_0..GC_6, PS_0..PS_3 as a codec of projector columns.

    With ``l = (u + 0.5) nlp / width`` (code units): GC_k is bit k (MSB first) of the gray
    code of ``floor(l)``, so a word is ``width / nlp`` wide with origin -0.5; ``PS_i =
    0.5 + 0.5 cos(pi/2 l - i pi/2)``, so the phase has period ``4 width / nlp``, origin -0.5
    and shift -1. The gray bits are thresholded at the phase frames' mean A (no white or
    black frames). Frames are the eleven named files in that order.
    """
    if width <= 0 or height <= 0 or not 1 <= nlp <= 128:
        raise CodecError(f"gcps-v1 needs a positive projector size and nlp in 1..128, got {width}x{height}, {nlp}")
    return _gcps_v1_codec(width, height, nlp)


@functools.lru_cache(maxsize=32)
def _gcps_v1_codec(width: int, height: int, nlp: int) -> Codec:
    """:func:`gcps_v1_codec`, built once per size (every fused measurement's self-check asks for it:
    0.25 ms of parsing each time); a codec is frozen."""
    word = width / nlp
    from metrology.core.patterns import PATTERN_NAMES

    axis = Axis(
        phase=(PhaseSequence(frames=(7, 8, 9, 10), period=4 * word, shift=-1, origin=-0.5),),
        gray=GrayCode(frames=tuple(range(7)), word=word, order="msb_first", origin=-0.5),
    )
    return Codec(
        frames=tuple(PATTERN_NAMES),
        projector_width=width,
        projector_height=height,
        axes={"u": axis},
        name=GCPS_V1,
    )


def is_gcps_v1(codec: Codec | None) -> bool:
    """True for no codec (the paper's default) or the built-in gcps-v1 of any projector size."""
    return codec is None or codec.name == GCPS_V1


def builtin_codec(name: str) -> Codec:
    """A built-in codec by name: ``gcps-v1`` (1024x768 projector, 128 codes) or ``gcps-v1:WIDTHxHEIGHT``.

    Raises
    ------
    CodecError
        For an unknown name or a malformed size.
    """
    base, _, size = name.partition(":")
    if base != GCPS_V1:
        raise CodecError(f"unknown built-in codec {name!r}; built-in codecs: {', '.join(BUILTIN_NAMES)}")
    if not size:
        return gcps_v1_codec()
    m = re.fullmatch(r"(\d+)x(\d+)", size)
    if m is None:
        raise CodecError(f"built-in codec {name!r}: the size must be WIDTHxHEIGHT, e.g. gcps-v1:1280x800")
    return gcps_v1_codec(int(m.group(1)), int(m.group(2)))
