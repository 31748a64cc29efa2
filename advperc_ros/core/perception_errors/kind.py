"""What an error kind is: the record each module of `kinds/` fills in and the registry orders.

A kind is everything the rest of the code needs to know of one way a detector can be wrong, in one
place: its arrays in the error tensor, the error-space bounds that limit it, how it changes what
the attack function shows, how wrong it makes an object-frame (the guided search's wrongness), how
the metrics read it back from matched boxes, the search moves that make it, and what counts as
using it. The tensor, the attack function, the search, the metrics and the lockstep codec loop
over the registry instead of naming kinds, so adding one is a module and a registry line.
"""

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from advperc_ros.core.boxes import BoxSequence

if TYPE_CHECKING:
    from advperc_ros.core.perception_errors.tensor import ErrorSpace, PerceptionErrors


@dataclass(frozen=True)
class Bound:
    """A limit of the error space on one kind (`ErrorSpace.<name>`, the param `errors.<name>`): its
    default, the params reference's line (starting with the kind's name), and the range a params file
    may set (`low`/`high` inclusive, `positive`: above 0), checked as every param is."""

    name: str
    default: float | int
    description: str
    low: float | None = None
    high: float | None = None
    positive: bool = False


@dataclass(frozen=True)
class ArraySpec:
    """One array of the error tensor: what it holds when nothing is wrong (`neutral`), its element
    type, whether it is per frame and agent or per frame and ghost slot, and the floor its values
    keep (`above`: strictly; `at_least`: inclusive) that `PerceptionErrors.from_arrays` checks."""

    name: str
    neutral: bool | int | float
    dtype: type[np.generic] = np.float64
    per_ghost: bool = False
    above: float | None = None
    at_least: float | None = None

    def admits(self, array: np.ndarray) -> bool:
        """Whether every value keeps the floor."""
        if self.above is not None and not (array > self.above).all():
            return False
        return self.at_least is None or not (array < self.at_least).any()

    def floor(self) -> str:
        """The floor in words, for the error that names a value below it."""
        return f"above {self.above:g}" if self.above is not None else f"at least {self.at_least:g}"


@dataclass
class Shown:
    """What `inject` is making of one block of frames, each kind's `show` changing its share in turn:
    the truth the detections show (after a latency), the box fields they show, their validity, and
    the turn added to the truth's heading before it is wrapped (the yaw offset and a flip add up
    there, so a flipped heading is wrapped once, as one angle)."""

    source: dict[str, np.ndarray]
    boxes: dict[str, np.ndarray]
    valid: np.ndarray
    turn: np.ndarray | None = None


@dataclass(frozen=True)
class MatchedBoxes:
    """The devkit's greedy matching at the loosest threshold, as the metrics read a kind back from it:
    frame, prediction slot and truth slot of every match, and the in-range predictions no truth matched."""

    truth: BoxSequence
    perceived: BoxSequence
    frame: np.ndarray
    prediction: np.ndarray
    agent: np.ndarray
    unmatched: np.ndarray  # (frames x prediction slots) bool

    def at_matches(self, values: np.ndarray, neutral: float = 0.0) -> np.ndarray:
        """(frames x truth slots) `values` of the matches at their truth cells, `neutral` elsewhere."""
        out = np.full(self.truth.shape, neutral)
        out[self.frame, self.agent] = values
        return out

    def difference(self, field: str) -> np.ndarray:
        """The matched prediction's `field` minus its truth's, one value per match."""
        perceived, truth = getattr(self.perceived, field), getattr(self.truth, field)
        return perceived[self.frame, self.prediction] - truth[self.frame, self.agent]


@dataclass(frozen=True)
class MoveContext:
    """What the moves read besides the parent's errors: the truth, the parent's rollout, the error space."""

    truth: BoxSequence  # the scenario's agents
    ego: np.ndarray  # (K, 4) x, y, yaw, v of the parent's rollout
    space: "ErrorSpace"
    dt: float  # s between frames
    cars: np.ndarray | None = None  # (frames x slots) the object-frames the car moves may act on; None: any near


Move = Callable[["PerceptionErrors", int, np.random.Generator, MoveContext], "PerceptionErrors | None"]


@dataclass(frozen=True)
class ErrorKind:
    """One kind of perception error, all of it (module docstring). Every hook is optional: a kind
    without `show` changes nothing the attack function shows, one without `wrongness` makes no
    object-frame wrong to the guided search (a yaw error is noise), one without `read_back` is not
    read from matched boxes, and so on.

    - `paper`: one of the paper's kinds, whose arrays every tensor has; the others have theirs only
      when on;
    - `bounds`: the limits of the error space on it (`ErrorSpace.<name>`, the params `errors.<name>`);
    - `attacks`: whether an object-frame with this error alone counts as attacked;
    - `source(valid, errors, rows)`: the truth frame each detection of `rows` shows;
    - `show(shown, errors, rows)`: its change to the boxes, in place;
    - `slots(errors, rows)`: box fields of slots it adds after the agents' (frames x slots each);
    - `wrongness(errors, space)`: (frames x agents) in [0, 1], its share of its bound;
    - `read_back(matches)`: its arrays as a perception output shows them;
    - `used(errors, rows)`: whether its errors show in `rows` (default: an agent array off its
      neutral value on a frame the agent is not dropped);
    - `moves`: the guided and approach searches' moves that make it, by name.
    """

    name: str
    arrays: tuple[ArraySpec, ...]
    paper: bool = False
    bounds: tuple[Bound, ...] = ()
    attacks: bool = True
    source: Callable[[np.ndarray, "PerceptionErrors", slice], np.ndarray] | None = None
    show: Callable[[Shown, "PerceptionErrors", slice], None] | None = None
    slots: Callable[["PerceptionErrors", slice], dict[str, np.ndarray]] | None = None
    wrongness: Callable[["PerceptionErrors", "ErrorSpace"], np.ndarray] | None = None
    read_back: Callable[[MatchedBoxes], dict[str, np.ndarray]] | None = None
    used: Callable[["PerceptionErrors", slice], bool] | None = None
    moves: tuple[tuple[str, Move], ...] = ()

    @property
    def array_names(self) -> tuple[str, ...]:
        return tuple(spec.name for spec in self.arrays)

    def present(self, errors: "PerceptionErrors") -> bool:
        """Whether `errors` has this kind's arrays (a paper kind's always)."""
        return self.paper or getattr(errors, self.arrays[0].name) is not None
