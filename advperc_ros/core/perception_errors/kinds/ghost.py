"""Ghosts: per frame, detections of cars no agent explains, in slots after the agents'.

Its moves put a ghost car in the ego's path ahead for a run of frames, and switch the edges of a
ghost's run off (a move towards no error, as restoring the edges of a drop is). Bounded by
`ghosts` slots per frame. The metrics read it back as the in-range predictions no truth matched:
what the perception error model's false-positive term counts.
"""

from __future__ import annotations

from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from advperc_ros.core.geometry import wrap_angle
from advperc_ros.core.perception_errors.kind import ArraySpec, Bound, ErrorKind, MatchedBoxes, MoveContext
from advperc_ros.core.perception_errors.runs import dropped_runs, run_edge

if TYPE_CHECKING:
    from advperc_ros.core.perception_errors.tensor import PerceptionErrors

GHOST_CONFIDENCE_SEED = 20261127
# a ghost is a car no agent explains: a passenger car's box (m), whatever the scenario's cars are
GHOST_LENGTH, GHOST_WIDTH, GHOST_HEIGHT = 4.5, 1.8, 1.5
# a ghost's confidence ranks above this share of the real detections' (`ghost_scores`): the median, neither
# the cheapest false positive (below every true one) nor the dearest
GHOST_CONFIDENCE_QUANTILE = 0.5
GHOST_LEAD = (5, 40)  # frames ahead on the ego's own path where a ghost may stand
GHOST_FRAMES = 30  # frames a ghost stays on at most
GHOST_ASIDE = 1.5  # m a ghost may stand beside the ego's path: in its lane, or half in it


@lru_cache(maxsize=64)
def ghost_scores(num_frames: int, num_agents: int, ghosts: int) -> np.ndarray:
    """Confidence of ghost slot g at frame k: every ghost inside one narrow band between two adjacent
    real confidences, the band above the share `GHOST_CONFIDENCE_QUANTILE` of the real ones.

    A ghost's cost in AP is its rank among the real detections (a false positive below every true
    one costs almost nothing). Were the score fixed per slot or per place, the search would learn to
    switch on only the low-scored ghosts, a stealth no detector has (its false positives are scored
    by the same network as its true ones). In one band every ghost outranks the same real detections
    whatever the attack does; the band's own order (a second fixed permutation) only decides between
    two ghosts that compete for one car, and is never chosen either. No score ties a real one.
    """
    real = num_frames * num_agents
    below = round(GHOST_CONFIDENCE_QUANTILE * real)  # real confidences (r + 1) / (real + 1) below the band: r < below
    count = num_frames * ghosts
    rank = np.random.default_rng(GHOST_CONFIDENCE_SEED).permutation(count)
    scores = ((below + (rank + 1.0) / (count + 1.0)) / (real + 1.0)).reshape(num_frames, ghosts)
    scores.setflags(write=False)
    return scores


def _slots(errors: PerceptionErrors, rows: slice) -> dict[str, np.ndarray]:
    """The ghost slots' boxes: ids -1, -2, ... (never an agent's)."""
    assert errors.ghost_on is not None and errors.ghost_x is not None and errors.ghost_y is not None
    assert errors.ghost_yaw is not None and errors.ghost_vx is not None and errors.ghost_vy is not None
    shape = errors.ghost_on[rows].shape
    return {
        "ids": np.broadcast_to(-1 - np.arange(shape[1], dtype=np.int64), shape), "valid": errors.ghost_on[rows],
        "x": errors.ghost_x[rows], "y": errors.ghost_y[rows], "yaw": wrap_angle(errors.ghost_yaw[rows]),
        "vx": errors.ghost_vx[rows], "vy": errors.ghost_vy[rows], "length": np.full(shape, GHOST_LENGTH),
        "width": np.full(shape, GHOST_WIDTH), "height": np.full(shape, GHOST_HEIGHT),
        "score": ghost_scores(errors.shape[0], errors.shape[1], shape[1])[rows],
    }


def _read_back(matches: MatchedBoxes) -> dict[str, np.ndarray]:
    """One slot per prediction slot, on where the prediction is a false positive in range; the
    predictions' own arrays, read, never written."""
    perceived = matches.perceived
    return {"ghost_on": matches.unmatched, "ghost_x": perceived.x, "ghost_y": perceived.y, "ghost_yaw": perceived.yaw,
            "ghost_vx": perceived.vx, "ghost_vy": perceived.vy}


def _used(errors: PerceptionErrors, rows: slice) -> bool:
    return errors.ghost_on is not None and bool(errors.ghost_on[rows].any())


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


KIND = ErrorKind(
    name="ghost",
    arrays=(ArraySpec("ghost_on", False, np.bool_, per_ghost=True),
            *(ArraySpec(name, 0.0, per_ghost=True) for name in ("ghost_x", "ghost_y", "ghost_yaw", "ghost_vx",
                                                                 "ghost_vy"))),
    bounds=(Bound("ghosts", 2, "ghost kind: ghost detections per frame at most", low=1, high=64),),
    slots=_slots, read_back=_read_back, used=_used,
    moves=(("ghost_ahead", ghost_ahead), ("ghost_gone", ghost_gone)),
)
