"""A velocity error: the detection's velocity wrong by (dvx, dvy), world frame.

Its move shows a run of a car slower or faster than it is along its heading: our tracker and most
trackers take a new track's velocity from its first detection, so a car detected again after a drop
arrives with it. Bounded by `max_speed_error` in each axis, its wrongness is the error's norm over it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from advperc_ros.core.perception_errors.kind import ArraySpec, Bound, ErrorKind, MatchedBoxes, MoveContext, Shown
from advperc_ros.core.perception_errors.moves import car_move

if TYPE_CHECKING:
    from advperc_ros.core.perception_errors.tensor import ErrorSpace, PerceptionErrors


def _show(shown: Shown, errors: PerceptionErrors, rows: slice) -> None:
    assert errors.dvx is not None and errors.dvy is not None
    shown.boxes["vx"], shown.boxes["vy"] = shown.source["vx"] + errors.dvx[rows], shown.source["vy"] + errors.dvy[rows]


def _wrongness(errors: PerceptionErrors, space: ErrorSpace) -> np.ndarray:
    assert errors.dvx is not None and errors.dvy is not None
    return np.minimum(np.hypot(errors.dvx, errors.dvy) / space.max_speed_error, 1.0)


def _read_back(matches: MatchedBoxes) -> dict[str, np.ndarray]:
    return {"dvx": matches.at_matches(matches.difference("vx")), "dvy": matches.at_matches(matches.difference("vy"))}


def _wrong_velocity(out: PerceptionErrors, j: int, rows: slice, rng: np.random.Generator, context: MoveContext) -> None:
    """A run of a car shown with its velocity along its heading wrong by U(-max, max)."""
    assert out.dvx is not None and out.dvy is not None
    speed = rng.uniform(-context.space.max_speed_error, context.space.max_speed_error)
    yaw = context.truth.yaw[rows, j]
    out.dvx[rows, j], out.dvy[rows, j] = speed * np.cos(yaw), speed * np.sin(yaw)


faster_or_slower = car_move("velocity", _wrong_velocity)

KIND = ErrorKind(
    name="velocity", arrays=(ArraySpec("dvx", 0.0), ArraySpec("dvy", 0.0)), bounds=(
        Bound("max_speed_error", 5.0, "velocity kind: the largest error of a detection's velocity (m/s)", positive=True,
              high=100.0),),
    show=_show, wrongness=_wrongness, read_back=_read_back,
    moves=(("faster_or_slower", faster_or_slower),),
)
