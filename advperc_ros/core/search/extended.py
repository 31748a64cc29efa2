"""The guided search's moves of the error kinds beyond the paper's, one family per kind (`errors.kinds`).

Each move is what such an error does to a planner in the field, drawn at random as the paper's
proposals are and scored exactly before any rollout: a car shown slower or faster than it is (our
tracker and most trackers take a new track's velocity from its first detection, so a car detected
again after a drop arrives with it), shown larger or smaller (a planner's clearance), turned around
(a prediction that points away), shown late (where it was a few frames ago: a car braking ahead
seems further away and faster, a crossing car further from the conflict), and ghosts in the ego's
path ahead, switched on and off. The first four act on a run of frames of one car: an attacked run
(the failure mode so far involves it) or, half the time, any run of a car within range, as the
paper's errors need not all hide a car; the car is shown (no longer dropped) on those frames.
"""

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.metrics.nds import CLASS_RANGE
from advperc_ros.core.perception_errors import ErrorSpace, PerceptionErrors
from advperc_ros.core.search.refine import attacked_runs, dropped_runs, run_edge

GHOST_LEAD = (5, 40)  # frames ahead on the ego's own path where a ghost may stand
GHOST_FRAMES = 30  # frames a ghost stays on at most
GHOST_ASIDE = 1.5  # m a ghost may stand beside the ego's path: in its lane, or half in it


@dataclass(frozen=True)
class MoveContext:
    """What the moves read besides the parent's errors: the truth, the parent's rollout, the error space."""

    truth: BoxSequence  # the scenario's agents
    ego: np.ndarray  # (K, 4) x, y, yaw, v of the parent's rollout
    space: ErrorSpace
    dt: float  # s between frames
    cars: np.ndarray | None = None  # (frames x slots) the object-frames the car moves may act on; None: any near


Move = Callable[[PerceptionErrors, int, np.random.Generator, MoveContext], PerceptionErrors | None]


def _car_run(errors: PerceptionErrors, frames: int, rng: np.random.Generator,
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


def _car_move(kind: str, change: Callable[[PerceptionErrors, int, slice, np.random.Generator, MoveContext], None]) -> Move:
    """The move that shows a car's run (`_car_run`; no longer dropped there) with `kind`'s error that
    `change` makes in place on (errors with `kind`'s arrays, slot, frames); None when there is no run."""

    def move(errors: PerceptionErrors, frames: int, rng: np.random.Generator,
             context: MoveContext) -> PerceptionErrors | None:
        run = _car_run(errors, frames, rng, context)
        if run is None:
            return None
        j, a, b = run
        out = errors.with_kind(kind).copy()
        out.fn[a : b + 1, j] = False
        change(out, j, slice(a, b + 1), rng, context)
        return out

    move.__doc__ = change.__doc__
    return move


def _wrong_velocity(out: PerceptionErrors, j: int, rows: slice, rng: np.random.Generator, context: MoveContext) -> None:
    """A run of a car shown with its velocity along its heading wrong by U(-max, max)."""
    assert out.dvx is not None and out.dvy is not None
    speed = rng.uniform(-context.space.max_speed_error, context.space.max_speed_error)
    yaw = context.truth.yaw[rows, j]
    out.dvx[rows, j], out.dvy[rows, j] = speed * np.cos(yaw), speed * np.sin(yaw)


def _wrong_size(out: PerceptionErrors, j: int, rows: slice, rng: np.random.Generator, context: MoveContext) -> None:
    """A run of a car shown with its length and width each scaled by a factor uniform in the bounds."""
    assert out.length_scale is not None and out.width_scale is not None
    out.length_scale[rows, j], out.width_scale[rows, j] = rng.uniform(context.space.min_scale, context.space.max_scale,
                                                                      size=2)


def _heading_flipped(out: PerceptionErrors, j: int, rows: slice, rng: np.random.Generator, context: MoveContext) -> None:
    """A run of a car shown heading the other way."""
    assert out.flip is not None
    out.flip[rows, j] = True


def _lagging(out: PerceptionErrors, j: int, rows: slice, rng: np.random.Generator, context: MoveContext) -> None:
    """A run of a car shown as it was 1..max_latency frames before (a drop becomes a late detection,
    the lag its only error there)."""
    assert out.latency is not None
    out.perceive_perfectly(rows.start, rows.stop - 1, j)
    out.latency[rows, j] = rng.integers(1, context.space.max_latency + 1)


faster_or_slower = _car_move("velocity", _wrong_velocity)
resized = _car_move("size", _wrong_size)
turned_around = _car_move("flip", _heading_flipped)
late = _car_move("latency", _lagging)


def ghost_ahead(errors: PerceptionErrors, frames: int, rng: np.random.Generator,
                context: MoveContext) -> PerceptionErrors | None:
    """A ghost car on the ego's own path some frames ahead of it (up to `GHOST_ASIDE` beside it), for a
    run of frames, standing or driving the ego's way slower than the ego; in a ghost slot free over that
    run if there is one."""
    if frames < 1:
        return None
    out = errors.with_kind("ghost", context.space.ghosts).copy()
    assert out.ghost_on is not None and out.ghost_x is not None and out.ghost_y is not None
    assert out.ghost_yaw is not None and out.ghost_vx is not None and out.ghost_vy is not None
    a = int(rng.integers(frames))
    b = min(frames - 1, a + int(rng.integers(GHOST_FRAMES)))
    free = np.flatnonzero(~out.ghost_on[a : b + 1].any(axis=0))
    g = int(free[0]) if free.size else int(rng.integers(out.ghost_slots))
    ego = context.ego
    x, y, yaw, v = ego[min(a + int(rng.integers(*GHOST_LEAD)), len(ego) - 1)]
    speed = rng.uniform(0.0, max(float(v), 0.0)) * rng.integers(2)  # half the ghosts stand still
    aside = rng.uniform(-GHOST_ASIDE, GHOST_ASIDE)
    x, y = x - aside * np.sin(yaw), y + aside * np.cos(yaw)
    t = np.arange(b - a + 1) * context.dt
    out.ghost_on[a : b + 1, g] = True
    out.ghost_x[a : b + 1, g] = x + speed * np.cos(yaw) * t
    out.ghost_y[a : b + 1, g] = y + speed * np.sin(yaw) * t
    out.ghost_yaw[a : b + 1, g] = yaw
    out.ghost_vx[a : b + 1, g], out.ghost_vy[a : b + 1, g] = speed * np.cos(yaw), speed * np.sin(yaw)
    return out


def ghost_gone(errors: PerceptionErrors, frames: int, rng: np.random.Generator,
               context: MoveContext) -> PerceptionErrors | None:
    """The first or last k frames of a ghost's run switched off (k up to half the run): a move towards
    no error, as restoring the edges of a drop is."""
    if errors.ghost_on is None:
        return None
    runs = dropped_runs(errors.ghost_on[:frames])
    if not runs:
        return None
    g, first, last = runs[rng.integers(len(runs))]
    a, b = run_edge(first, last, rng)
    out = errors.copy()
    assert out.ghost_on is not None
    out.ghost_on[a : b + 1, g] = False
    return out


# each extended kind's moves, by name, in the order the guided search's move list holds them
MOVES_OF_KIND: dict[str, tuple[tuple[str, Move], ...]] = {
    "velocity": (("faster_or_slower", faster_or_slower),),
    "size": (("resized", resized),),
    "flip": (("turned_around", turned_around),),
    "latency": (("late", late),),
    "ghost": (("ghost_ahead", ghost_ahead), ("ghost_gone", ghost_gone)),
}
