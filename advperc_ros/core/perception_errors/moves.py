"""What the search moves of the kinds that act on one car share: the run of frames a move picks, and
the move made of a kind's change to it.

Each move is what such an error does to a planner in the field, drawn at random as the paper's
proposals are and scored exactly before any rollout. A car move acts on a run of frames of one car:
an attacked run (the failure mode so far involves it) or, half the time, any run of a car within
range, as the paper's errors need not all hide a car; the car is shown (no longer dropped) on those
frames.
"""

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from advperc_ros.core.boxes import CLASS_RANGE
from advperc_ros.core.perception_errors.kind import Move, MoveContext
from advperc_ros.core.perception_errors.runs import attacked_runs, dropped_runs

if TYPE_CHECKING:
    from advperc_ros.core.perception_errors.tensor import PerceptionErrors

Change = Callable[["PerceptionErrors", int, slice, np.random.Generator, MoveContext], None]


def car_run(errors: "PerceptionErrors", frames: int, rng: np.random.Generator,
            context: MoveContext) -> tuple[int, int, int] | None:
    """(slot, first, last): a uniform sub-run of an attacked run, or half the time (or when nothing is
    attacked yet) of a run of a car present within range of the ego; of a run of `context.cars` if given."""
    runs = attacked_runs(errors, frames) if context.cars is None else dropped_runs(context.cars[:frames])
    if context.cars is None and (not runs or rng.integers(2)):
        ego = context.ego[:frames, :2]
        near = context.truth.valid[:frames] & (np.hypot(context.truth.x[:frames] - ego[:, :1],
                                                        context.truth.y[:frames] - ego[:, 1:]) < CLASS_RANGE)
        runs = dropped_runs(near) or runs
    if not runs:
        return None
    j, a, b = runs[rng.integers(len(runs))]
    a, b = np.sort(rng.integers(a, b + 1, size=2))
    return j, int(a), int(b)


def car_move(kind: str, change: Change) -> Move:
    """The move that shows a car's run (`car_run`; no longer dropped there) with `kind`'s error that
    `change` makes in place on (errors with `kind`'s arrays, slot, frames); None when there is no run."""

    def move(errors: "PerceptionErrors", frames: int, rng: np.random.Generator,
             context: MoveContext) -> "PerceptionErrors | None":
        run = car_run(errors, frames, rng, context)
        if run is None:
            return None
        j, a, b = run
        out = errors.with_kind(kind).copy()
        out.fn[a : b + 1, j] = False
        change(out, j, slice(a, b + 1), rng, context)
        return out

    move.__doc__ = change.__doc__
    return move
