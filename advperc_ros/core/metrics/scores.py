"""Everything a report says of a perception output: NDS, NDS-t and the Table 1 columns.

A ground-truth object-frame counts when the agent is present and within 50 m of the ego. It is a
true positive when the devkit's greedy matching pairs it with a detection at the loosest NDS
threshold (4 m), and a false negative otherwise; MPE and MAOE average over the true positives.
This is the paper's false-negative switch read from the perception output alone: a detection
within 4 m still earns NDS credit, so only what no threshold credits counts as a drop, for the
Table 1 counts and for NDS-t's longest drop fraction alike.
"""

from dataclasses import asdict, dataclass

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import wrap_angle
from advperc_ros.core.metrics.nds import DIST_THRESHOLDS, nds


@dataclass(frozen=True)
class PerceptionScores:
    nds: float
    nds_t: float
    longest_drop_fraction: float
    mean_ap: float
    tp: int
    fn: int
    fp: int
    mpe: float  # m, mean position error over true positives (nan without any)
    maoe: float  # rad, mean absolute orientation error over true positives (nan without any)

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)


def longest_drop_fraction(missed: np.ndarray, counted: np.ndarray) -> float:
    """Max over agents of (longest run of consecutive misses) / (frames the agent counts).

    missed, counted: (F, G) bool with agent-consistent columns; runs are taken over the frames in
    which the agent counts (present and in range).
    """
    worst = 0.0
    for j in np.flatnonzero(counted.any(axis=0)):
        seq = missed[counted[:, j], j].astype(np.int8)
        edges = np.diff(np.concatenate([[0], seq, [0]]))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        if starts.size:
            worst = max(worst, float((ends - starts).max()) / seq.size)
    return worst


def score(gt: BoxSequence, pred: BoxSequence, ego_xy: np.ndarray) -> PerceptionScores:
    """All perception metrics of `pred` against `gt` (same frames; gt slots are agents)."""
    result = nds(gt, pred, ego_xy)
    pred_gt = result.matchings[max(DIST_THRESHOLDS)].pred_gt
    f, p = np.nonzero(pred_gt >= 0)
    g = pred_gt[f, p]
    matched = np.zeros(gt.shape, dtype=bool)
    matched[f, g] = True
    counted = result.gt_in_range
    missed = counted & ~matched
    ldf = longest_drop_fraction(missed, counted)
    tp = int(f.size)
    position_error = np.hypot(pred.x[f, p] - gt.x[f, g], pred.y[f, p] - gt.y[f, g])
    orientation_error = np.abs(wrap_angle(pred.yaw[f, p] - gt.yaw[f, g]))
    return PerceptionScores(
        nds=result.nds,
        nds_t=(result.nds + (1.0 - ldf)) / 2.0,
        longest_drop_fraction=ldf,
        mean_ap=result.mean_ap,
        tp=tp,
        fn=int(missed.sum()),
        fp=int(result.pred_in_range.sum()) - tp,
        mpe=float(position_error.mean()) if tp else float("nan"),
        maoe=float(orientation_error.mean()) if tp else float("nan"),
    )
