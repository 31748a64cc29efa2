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
from advperc_ros.core.metrics.nds import DIST_THRESHOLDS, NDSResult, nds
from advperc_ros.core.pem import PEM, default_pem
from advperc_ros.core.perception_errors import MatchedBoxes, PerceptionErrors, registry


@dataclass(frozen=True)
class PerceptionScores:
    """Every perception metric of one rollout's perceived boxes against ground truth: the search
    maximises one (`objective`), the report shows them all (the paper's Table 1 columns)."""

    nds: float
    nds_t: float
    longest_drop_fraction: float
    mean_ap: float
    tp: int
    fn: int
    fp: int
    mpe: float  # m, mean position error over true positives (nan without any)
    maoe: float  # rad, mean absolute orientation error over true positives (nan without any)
    pem_ll: float  # mean log-likelihood per counted object-frame under the perception error model

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)


def nds_t_score(nds: float, longest_drop: float) -> float:
    """NDS-t: NDS and the share of its frames an agent is not missed in a row, weighed alike."""
    return (nds + (1.0 - longest_drop)) / 2.0


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


def matched_errors(gt: BoxSequence, pred: BoxSequence, ego_xy: np.ndarray, beyond_the_paper: bool = True
                   ) -> tuple[PerceptionErrors, np.ndarray, NDSResult]:
    """The errors a perception output made, read off the devkit's greedy matching at 4 m.

    Returns (errors, counted, nds result): errors[k, j] holds the offset and yaw error of the
    detection matched to gt slot j at frame k, fn where none matched; `beyond_the_paper`, also what
    the other kinds read back (`ErrorKind.read_back`): its velocity error and size scales, and ghost
    slots, one per prediction slot, that hold the false positives (the in-range predictions no truth
    matched, as `fp` counts them): what the perception error model's terms beyond the paper read, left
    out when no term will. counted marks gt present within 50 m.
    """
    result = nds(gt, pred, ego_xy)
    pred_gt = result.matchings[max(DIST_THRESHOLDS)].pred_gt
    f, p = np.nonzero(pred_gt >= 0)
    matches = MatchedBoxes(gt, pred, f, p, pred_gt[f, p], result.pred_in_range & (pred_gt < 0))
    arrays: dict[str, np.ndarray] = {}
    for kind in registry.KINDS:
        if kind.read_back is not None and (kind.paper or beyond_the_paper):
            arrays.update(kind.read_back(matches))
    return PerceptionErrors.of(**arrays), result.gt_in_range, result


def score(
    gt: BoxSequence, pred: BoxSequence, ego_xy: np.ndarray, pem: PEM | None = None, phi: np.ndarray | None = None
) -> PerceptionScores:
    """All perception metrics of `pred` against `gt` (same frames; gt slots are agents).

    PEM LL reads the errors off the same 4 m matching: a matched car is detected with the error
    of its match, an unmatched one is missed, an unmatched detection in range is a false positive
    (the paper's kinds' default model unless `pem` is given: errors of other kinds are scored by
    `default_pem(kinds)`; `phi`, the model's features of gt seen from ego_xy, may be passed in to
    score many outputs on one rollout).
    """
    model = pem or default_pem()
    errors, counted, result = matched_errors(gt, pred, ego_xy, model.reads_beyond_the_paper)
    matched = counted & ~errors.fn
    missed = counted & errors.fn
    ldf = longest_drop_fraction(missed, counted)
    tp = int(matched.sum())
    position_error = np.hypot(errors.dx[matched], errors.dy[matched])
    orientation_error = np.abs(errors.dyaw[matched])
    return PerceptionScores(
        nds=result.nds,
        nds_t=nds_t_score(result.nds, ldf),
        longest_drop_fraction=ldf,
        mean_ap=result.mean_ap,
        tp=tp,
        fn=int(missed.sum()),
        fp=int(result.pred_in_range.sum()) - tp,
        mpe=float(position_error.mean()) if tp else float("nan"),
        maoe=float(orientation_error.mean()) if tp else float("nan"),
        pem_ll=model.score(gt, errors, ego_xy, counted, phi),
    )
