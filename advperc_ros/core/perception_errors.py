"""The paper's error tensor e and attack function I(y, e).

e holds, per frame and agent, a world-frame position offset, a yaw offset and a false-negative
flag. Size and velocity of a detection stay true (the paper gives the tracker ground truth for
everything it does not attack).
"""

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import wrap_angle

CONFIDENCE_SEED = 20240617


@dataclass(frozen=True)
class PerceptionErrors:
    """The paper's error tensor e: per frame and agent, a position and yaw offset and a dropped flag.
    Everything the search changes is in it and nothing else, so an attack is this tensor; it is
    saved with the results (attack_errors.npz) and replayed from there."""

    dx: np.ndarray  # (T, N) metres
    dy: np.ndarray  # (T, N) metres
    dyaw: np.ndarray  # (T, N) rad
    fn: np.ndarray  # (T, N) bool, True drops the detection

    @classmethod
    def none(cls, num_frames: int, num_agents: int) -> "PerceptionErrors":
        shape = (num_frames, num_agents)
        return cls(np.zeros(shape), np.zeros(shape), np.zeros(shape), np.zeros(shape, dtype=bool))

    @property
    def shape(self) -> tuple[int, int]:
        return self.fn.shape

    def copy(self) -> "PerceptionErrors":
        return PerceptionErrors(self.dx.copy(), self.dy.copy(), self.dyaw.copy(), self.fn.copy())

    def with_drop(self, agent: int, start: int, end: int) -> "PerceptionErrors":
        """These errors plus agent `agent` dropped on frames start..end inclusive."""
        out = self.copy()
        out.fn[start : end + 1, agent] = True
        return out

    def equals(self, other: "PerceptionErrors") -> bool:
        return all(
            np.array_equal(getattr(self, name), getattr(other, name)) for name in ("dx", "dy", "dyaw", "fn")
        )


@lru_cache(maxsize=64)
def confidence_scores(num_frames: int, num_agents: int) -> np.ndarray:
    """Confidence of the detection of agent j at frame k: strictly distinct, in (0, 1).

    A fixed pseudo-random permutation of the object-frames, independent of the errors, so an attack
    can neither exploit ties (the devkit would take ATE and AOE from a single box) nor choose which
    of its errors the precision-recall curve sees first.
    """
    count = num_frames * num_agents
    rank = np.random.default_rng(CONFIDENCE_SEED).permutation(count)
    scores = ((rank + 1.0) / (count + 1.0)).reshape(num_frames, num_agents)
    scores.setflags(write=False)
    return scores


def _offset(x: np.ndarray, y: np.ndarray, yaw: np.ndarray, dx: np.ndarray, dy: np.ndarray,
            dyaw: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The error of a detected box: its pose offset, yaw wrapped."""
    return x + dx, y + dy, wrap_angle(yaw + dyaw)


def inject(truth: BoxSequence, errors: PerceptionErrors) -> BoxSequence:
    """I(y, e): offset the true boxes and remove the dropped ones (whole sequences at once)."""
    if errors.shape != truth.shape:
        raise ValueError(f"error tensor shape {errors.shape} does not match ground truth {truth.shape}")
    x, y, yaw = _offset(truth.x, truth.y, truth.yaw, errors.dx, errors.dy, errors.dyaw)
    return replace(truth, valid=truth.valid & ~errors.fn, x=x, y=y, yaw=yaw, score=confidence_scores(*truth.shape))


def inject_frame(truth: dict[str, np.ndarray], frame: int, slots: np.ndarray,
                 errors: PerceptionErrors) -> dict[str, np.ndarray]:
    """I(y, e) for one frame, as the graph's injector node applies it: `truth` the frame's boxes
    (1-D arrays, as `BoxSequence.frame` gives them), `slots` the error-tensor column of each. The
    values are `inject`'s, float for float."""
    keep = ~errors.fn[frame, slots]
    kept = slots[keep]
    out = {name: values[keep] for name, values in truth.items()}
    out["x"], out["y"], out["yaw"] = _offset(out["x"], out["y"], out["yaw"], errors.dx[frame, kept],
                                             errors.dy[frame, kept], errors.dyaw[frame, kept])
    out["score"] = confidence_scores(*errors.shape)[frame, kept]
    return out
