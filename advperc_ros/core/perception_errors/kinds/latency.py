"""A latency: the detection shows its agent as it was some frames earlier.

Its move shows a run of a car late, where it was a few frames ago (a car braking ahead seems
further away and faster, a crossing car further from the conflict); a drop there becomes a late
detection, the lag its only error. Bounded by `max_latency`, its wrongness is the lag over it. The
metrics do not read it back: a late match is a position, yaw and velocity error from the present
truth, which the perception error model's latency term explains.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from advperc_ros.core.perception_errors.kind import ArraySpec, Bound, ErrorKind, MoveContext
from advperc_ros.core.perception_errors.moves import car_move

if TYPE_CHECKING:
    from advperc_ros.core.perception_errors.tensor import ErrorSpace, PerceptionErrors


def latency_source(valid: np.ndarray, latency: np.ndarray, rows: slice) -> np.ndarray:
    """The frame each detection of `rows` shows: `latency` frames back, but never before the agent's
    present appearance (an agent that was absent in between is shown as it was when it came back),
    so a late detection is always of a car that was there. Reads only frames up to the rows' own,
    which is what lets the injector node answer each frame as it arrives."""
    frames = np.arange(valid.shape[0])[rows][:, None]
    lag = latency[rows]
    source = np.repeat(frames, valid.shape[1], axis=1)
    agents = np.arange(valid.shape[1])
    going = valid[rows].copy()  # an absent car is not shown: its own frame, as for no latency
    for back in range(1, int(lag.max(initial=0)) + 1):
        earlier = frames - back
        going &= (back <= lag) & (earlier >= 0) & valid[np.maximum(earlier, 0), agents]
        source[going] = np.broadcast_to(earlier, source.shape)[going]
    return source


def _source(valid: np.ndarray, errors: PerceptionErrors, rows: slice) -> np.ndarray:
    assert errors.latency is not None
    return latency_source(valid, errors.latency, rows)


def _wrongness(errors: PerceptionErrors, space: ErrorSpace) -> np.ndarray:
    assert errors.latency is not None
    return np.minimum(errors.latency / space.max_latency, 1.0)


def _lagging(out: PerceptionErrors, j: int, rows: slice, rng: np.random.Generator, context: MoveContext) -> None:
    """A run of a car shown as it was 1..max_latency frames before (a drop becomes a late detection,
    the lag its only error there)."""
    assert out.latency is not None
    out.perceive_perfectly(rows.start, rows.stop - 1, j)
    out.latency[rows, j] = rng.integers(1, context.space.max_latency + 1)


late = car_move("latency", _lagging)

KIND = ErrorKind(
    name="latency", arrays=(ArraySpec("latency", 0, np.int64, at_least=0.0),),
    bounds=(Bound("max_latency", 5, "latency kind: the most frames a detection may lag behind its car", low=1,
                  high=100),),
    source=_source, wrongness=_wrongness, moves=(("late", late),),
)
