"""Per-frame synchronisation and exposure checks, and the auto-exposure helper.

Notation (all per camera pixel, grey levels of the camera's depth, full scale ``F``): ``W`` and
``B`` the frames grabbed under a white and a black projector frame, contrast ``C = W - B``; a
pixel is *lit* when ``C >= min_contrast * F``. For a frame ``I_k`` grabbed under projector
pattern ``P_k`` (uint8 projector image) after ``I_{k-1}`` under ``P_{k-1}``:

- **saturated fraction**: pixels at full scale (``I >= F``), fraction of all pixels; a frame is
  refused when it has more than the white frame plus ``max_extra_saturated`` (no pattern can be
  brighter than white, so excess saturation means a bad frame);
- **dark fraction**: pixels at or below ``dark_level * F``, fraction of all pixels (reported; on
  the white frame it measures under-exposure);
- **range**: ``n = (I - B) / C`` on lit pixels; a frame is refused when more than
  ``max_out_of_range`` of them lie outside ``[-0.25, 1.25]``;
- **change**: the fraction of lit pixels with ``|I_k - I_{k-1}| > change_level * C``, compared
  with the fraction of projector pixels with ``|P_k - P_{k-1}| > change_level * 255``; a frame is
  refused when it changed by less than ``min_change_ratio`` times the expected fraction (the
  camera returned the previous pattern's frame: latency);
- **correlation** (when the camera knows the expected image, e.g. the virtual rig): Pearson's
  correlation of ``I_k`` with the expected image over lit pixels, refused below
  ``min_correlation``; tested only where the expected image's spread over the lit pixels reaches
  ``min_contrast`` of their median contrast ``C`` (else there is no pattern to recognise); a flat
  frame there (no spread at all: a late, noise-free black frame) has correlation 0.

The white frame itself is refused when fewer than ``min_lit_fraction`` of the pixels are lit
(the camera saw no projector light: it returned the black frame, or the projector is off), or
when more than ``max_white_saturated`` of them are at full scale (over-exposed; a bracket's longer
exposures saturate the bright part on purpose and allow it: docs/exposures.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class CheckOptions:
    """Thresholds of the frame checks (fractions; see the module docstring)."""

    min_contrast: float = 0.05
    min_lit_fraction: float = 0.02
    dark_level: float = 0.02
    max_extra_saturated: float = 0.01
    max_white_saturated: float = 0.01
    max_out_of_range: float = 0.05
    change_level: float = 0.25
    min_change_ratio: float = 0.4
    min_correlation: float = 0.8

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not (isinstance(value, int | float) and 0.0 <= float(value) <= 1.0):
                raise ValueError(f"check option {name} must be a fraction in [0, 1], got {value!r}")


@dataclass
class FrameCheck:
    """The checks of one grabbed frame of camera ``camera`` (0 on a one-camera rig). ``ok`` is False
    with ``reasons`` when it is refused."""

    name: str
    kind: str
    frame: int
    grab: int
    camera: int = 0
    ok: bool = True
    reasons: list[str] = field(default_factory=list)
    saturated_fraction: float = 0.0
    dark_fraction: float = 0.0
    lit_fraction: float | None = None
    out_of_range_fraction: float | None = None
    change_fraction: float | None = None
    expected_change: float | None = None
    correlation: float | None = None
    mean_grey: float = 0.0

    def refuse(self, reason: str) -> None:
        self.ok = False
        self.reasons.append(reason)

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        return {k: (round(v, 5) if isinstance(v, float) else v) for k, v in data.items()}


def full_scale(image: np.ndarray) -> int:
    """255 for uint8 images, 65535 for uint16; ValueError otherwise."""
    if image.dtype == np.uint8:
        return 255
    if image.dtype == np.uint16:
        return 65535
    raise ValueError(f"camera frames must be uint8 or uint16, got {image.dtype}")


def projector_change(previous: np.ndarray | None, current: np.ndarray | None, level: float) -> float | None:
    """Fraction of projector pixels with ``|P_k - P_{k-1}| > level * 255`` (None when unknown)."""
    if previous is None or current is None:
        return None
    diff = np.abs(current.astype(np.int16) - previous.astype(np.int16))
    return float(np.mean(diff > level * 255))


class FrameChecker:
    """Checks frames of camera ``camera`` against its white and black frames of the same acquisition."""

    def __init__(self, options: CheckOptions | None = None, camera: int = 0) -> None:
        self.options = options or CheckOptions()
        self.camera = camera
        self.white: np.ndarray | None = None
        self.black: np.ndarray | None = None
        self.lit: np.ndarray | None = None
        self.contrast: np.ndarray | None = None
        self.white_saturated = 0.0

    def _basic(self, check: FrameCheck, image: np.ndarray) -> int:
        full = full_scale(image)
        check.saturated_fraction = float(np.mean(image >= full))
        check.dark_fraction = float(np.mean(image <= self.options.dark_level * full))
        check.mean_grey = float(image.mean())
        return full

    def check_black(self, image: np.ndarray, name: str = "black", grab: int = 1) -> FrameCheck:
        """The black frame: only exposure figures (nothing to compare with yet)."""
        check = FrameCheck(name=name, kind="black", frame=-1, grab=grab, camera=self.camera)
        self._basic(check, image)
        return check

    def check_white(
        self,
        white: np.ndarray,
        black: np.ndarray,
        name: str = "white",
        grab: int = 1,
        black_after: np.ndarray | None = None,
    ) -> FrameCheck:
        """The white frame against the black one: lit fraction, saturation. Sets the reference frames if ok.

        ``black_after``, a black frame grabbed after the white one, must agree with ``black``: on more
        than ``max_out_of_range`` of the lit pixels ``|B_after - B| > change_level * C`` refuses the
        pair (one of the black frames was late or saturated).
        """
        if white.shape != black.shape or white.dtype != black.dtype:
            raise ValueError(f"white and black frames differ: {white.shape} {white.dtype}, {black.shape} {black.dtype}")
        check = FrameCheck(name=name, kind="white", frame=-1, grab=grab, camera=self.camera)
        full = self._basic(check, white)
        contrast = white.astype(np.float32) - black.astype(np.float32)
        lit = contrast >= self.options.min_contrast * full
        check.lit_fraction = float(lit.mean())
        if check.lit_fraction < self.options.min_lit_fraction:
            check.refuse(
                f"white frame shows no projector light: {100 * check.lit_fraction:.1f} % of the pixels brighter "
                f"than the black frame by {100 * self.options.min_contrast:.0f} % of full scale"
            )
        elif check.saturated_fraction > self.options.max_white_saturated:
            check.refuse(
                f"white frame saturated: {100 * check.saturated_fraction:.2f} % of the pixels at full scale "
                "(lower the exposure)"
            )
        elif black_after is not None:
            differ = np.abs(black_after.astype(np.float32) - black.astype(np.float32)) > self.options.change_level * (
                np.maximum(contrast, 1.0)
            )
            disagree = float(differ[lit].mean())
            check.out_of_range_fraction = disagree
            if disagree > self.options.max_out_of_range:
                check.refuse(
                    f"the black frames before and after the white one disagree on {100 * disagree:.1f} % of the lit "
                    "pixels (a late or saturated black frame)"
                )
        if check.ok:
            self.white, self.black, self.lit, self.contrast = white, black, lit, np.maximum(contrast, 1.0)
            self.white_saturated = check.saturated_fraction
        return check

    def expected_change(self, previous: np.ndarray, current: np.ndarray) -> float:
        """Fraction of the lit pixels whose expected images (noise-free, e.g. the virtual rig's)
        differ by more than ``change_level`` times their contrast: the change to expect where the
        camera knows what it should see (where only part of the field is lit, as in the short
        exposure of a bracket, the projector's change overall says little about the lit part)."""
        if self.lit is None or self.contrast is None:
            raise ValueError("check the white and black frames first")
        diff = np.abs(current.astype(np.float32)[self.lit] - previous.astype(np.float32)[self.lit])
        return float(np.mean(diff > self.options.change_level * self.contrast[self.lit]))

    def check_frame(
        self,
        image: np.ndarray,
        *,
        name: str,
        frame: int,
        previous_image: np.ndarray,
        expected_change: float | None,
        expected_image: np.ndarray | None = None,
        grab: int = 1,
    ) -> FrameCheck:
        """A pattern frame: saturation, range, change from the previous frame, correlation."""
        if self.white is None or self.black is None or self.lit is None or self.contrast is None:
            raise ValueError("check the white and black frames first")
        if image.shape != self.white.shape or image.dtype != self.white.dtype:
            raise ValueError(f"frame {name}: {image.shape} {image.dtype}, the white frame {self.white.shape}")
        opts = self.options
        check = FrameCheck(name=name, kind="frame", frame=frame, grab=grab, camera=self.camera)
        self._basic(check, image)
        lit = self.lit
        values = image.astype(np.float32)[lit]
        contrast = self.contrast[lit]
        normalised = (values - self.black.astype(np.float32)[lit]) / contrast
        check.out_of_range_fraction = float(np.mean((normalised < -0.25) | (normalised > 1.25)))
        previous = previous_image.astype(np.float32)[lit]
        check.change_fraction = float(np.mean(np.abs(values - previous) > opts.change_level * contrast))
        check.expected_change = expected_change
        if check.saturated_fraction > self.white_saturated + opts.max_extra_saturated:
            check.refuse(
                f"saturated: {100 * check.saturated_fraction:.2f} % of the pixels at full scale, "
                f"the white frame has {100 * self.white_saturated:.2f} %"
            )
        if check.out_of_range_fraction > opts.max_out_of_range:
            check.refuse(f"{100 * check.out_of_range_fraction:.1f} % of the lit pixels outside the black-white range")
        if (
            expected_change is not None
            and expected_change > 0.05
            and check.change_fraction < opts.min_change_ratio * expected_change
        ):
            check.refuse(
                f"did not change from the previous frame: {100 * check.change_fraction:.1f} % of the lit pixels "
                f"changed, {100 * expected_change:.1f} % of the projector's did (previous pattern's frame?)"
            )
        if expected_image is not None:
            expected = expected_image.astype(np.float64)[lit]
            got = values.astype(np.float64)
            # only a pattern that varies across the lit pixels (more than the contrast test's
            # level of their median contrast) can be recognised: a frame whose lit pixels all lie in
            # one gray cell (a small bright patch at a short exposure) correlates with noise only
            varies = expected.std() >= opts.min_contrast * float(np.median(contrast))
            if varies:  # a flat frame where the pattern varies (the black frame, late) correlates 0
                check.correlation = float(np.corrcoef(expected, got)[0, 1]) if got.std() > 0 else 0.0
                if check.correlation < opts.min_correlation:
                    check.refuse(
                        f"correlation with the expected image {check.correlation:.3f} < {opts.min_correlation}"
                    )
        return check


def auto_exposure(
    grab_white: Callable[[float], np.ndarray],
    exposure_ms: float,
    *,
    target: float = 0.8,
    tolerance: float = 0.1,
    max_saturated: float = 0.002,
    max_iterations: int = 8,
    limits_ms: tuple[float, float] = (0.01, 60_000.0),
) -> tuple[float, list[dict[str, float]]]:
    """Pick the exposure (ms) that puts the white frame's 99th percentile at ``target`` of full scale.

    ``grab_white(exposure_ms)`` grabs a frame under the white pattern at that exposure. The sensor
    is taken as linear: ``e_next = e * target * F / p99`` (at most x4 or /4 per step); while more
    than ``max_saturated`` of the pixels are at full scale the exposure is halved instead.
    Stops when ``|p99 / F - target| <= tolerance`` with no excess saturation.

    Returns
    -------
    exposure_ms : float
        The chosen exposure.
    steps : list of dict
        ``{"exposure_ms", "p99", "saturated_fraction"}`` per grab (p99 as a fraction of full scale).

    Raises
    ------
    ValueError
        On a bad option, or when no exposure within the limits reaches the target.
    """
    if not 0 < target < 1 or not 0 < tolerance < target:
        raise ValueError(
            f"auto-exposure target must be in (0, 1) and tolerance in (0, target), got {target}, {tolerance}"
        )
    if not limits_ms[0] <= exposure_ms <= limits_ms[1]:
        raise ValueError(f"exposure {exposure_ms} ms is outside the camera's limits {limits_ms}")
    steps: list[dict[str, float]] = []
    e = float(exposure_ms)
    for _ in range(max_iterations):
        image = grab_white(e)
        full = full_scale(image)
        p99 = float(np.percentile(image, 99)) / full
        saturated = float(np.mean(image >= full))
        steps.append({"exposure_ms": e, "p99": p99, "saturated_fraction": saturated})
        if saturated > max_saturated:
            factor = 0.5
        elif abs(p99 - target) <= tolerance:
            return e, steps
        else:
            factor = min(4.0, max(0.25, target / max(p99, 1e-6)))
        nxt = min(limits_ms[1], max(limits_ms[0], e * factor))
        if nxt == e:
            break
        e = nxt
    raise ValueError(
        f"auto-exposure did not converge: white frame 99th percentile {100 * steps[-1]['p99']:.0f} % of full scale, "
        f"{100 * steps[-1]['saturated_fraction']:.2f} % saturated at {steps[-1]['exposure_ms']:.3g} ms"
    )
