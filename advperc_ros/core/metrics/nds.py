"""nuScenes detection score for the class car, as nuscenes-devkit 1.2.0 computes it, vectorised.

Config detection_cvpr_2019 restricted to cars: match thresholds 0.5/1/2/4 m on centre distance,
TP metrics at 2 m, class range 50 m around the ego (strict <, for truth and predictions alike),
greedy matching in descending confidence with strict <, 101-point interpolation, recall and
precision floors 0.1, AAE = 0 (truth and predictions share one attribute). Each frame is a sample.

The devkit matches predictions one by one in a Python loop; here the matching runs rank by rank
across all frames at once, since a prediction only competes with predictions of its own frame.
"""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.boxes import BoxSequence

DIST_THRESHOLDS = (0.5, 1.0, 2.0, 4.0)
TP_THRESHOLD = 2.0
CLASS_RANGE = 50.0
MIN_RECALL = 0.1
MIN_PRECISION = 0.1
MEAN_AP_WEIGHT = 5.0
NUM_POINTS = 101
FIRST_USEFUL = round(100 * MIN_RECALL) + 1  # interpolation points below the recall floor are ignored
TP_METRICS = ("trans_err", "scale_err", "orient_err", "vel_err", "attr_err")


@dataclass(frozen=True)
class Matching:
    """Greedy matching of one threshold: matched gt slot per prediction slot (-1: unmatched)."""

    pred_gt: np.ndarray  # (F, P) int


@dataclass(frozen=True)
class NDSResult:
    nds: float
    mean_ap: float
    ap: dict[float, float]
    tp_errors: dict[str, float]
    matchings: dict[float, Matching]  # per distance threshold, reused by NDS-t and the counts
    gt_in_range: np.ndarray  # (F, G) bool
    pred_in_range: np.ndarray  # (F, P) bool


def in_range(boxes: BoxSequence, ego_xy: np.ndarray) -> np.ndarray:
    dist = np.hypot(boxes.x - ego_xy[:, :1], boxes.y - ego_xy[:, 1:2])
    return boxes.valid & (dist < CLASS_RANGE)


def _prediction_order(scores: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Per frame, prediction slots by descending confidence; ties by descending slot (the
    devkit sorts (score, index) pairs and reverses); invalid slots last."""
    key = np.where(valid, scores, -np.inf)
    slots = np.broadcast_to(np.arange(scores.shape[1]), scores.shape)
    return np.lexsort((-slots, -key), axis=-1)


def greedy_match(
    dist: np.ndarray, order: np.ndarray, pred_ok: np.ndarray, gt_ok: np.ndarray, thresholds: tuple[float, ...]
) -> dict[float, Matching]:
    """The devkit's greedy matching for every threshold at once, one confidence rank at a time.

    dist (F, P, G) centre distances; each prediction takes the nearest untaken gt (first index on
    ties, as the devkit's strict <) and is a match if that distance is below the threshold.
    """
    num_frames, num_pred, num_gt = dist.shape
    ths = np.asarray(thresholds)[:, None]  # (H, 1)
    frames = np.arange(num_frames)
    taken = np.broadcast_to(~gt_ok, (len(thresholds), num_frames, num_gt)).copy()
    pred_gt = np.full((len(thresholds), num_frames, num_pred), -1)
    for rank in range(num_pred if num_gt else 0):
        p = order[:, rank]
        active = pred_ok[frames, p]
        d = np.where(taken, np.inf, dist[frames, p, :])  # (H, F, G)
        g = np.argmin(d, axis=2)  # (H, F)
        hit = active & (np.take_along_axis(d, g[:, :, None], axis=2)[:, :, 0] < ths)
        h_idx, f_idx = np.nonzero(hit)
        pred_gt[h_idx, f_idx, p[f_idx]] = g[h_idx, f_idx]
        taken[h_idx, f_idx, g[h_idx, f_idx]] = True
    return {th: Matching(pred_gt=pred_gt[i]) for i, th in enumerate(thresholds)}


def _angle_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    diff = (a - b + np.pi) % (2.0 * np.pi) - np.pi
    return np.abs(np.where(diff > np.pi, diff - 2.0 * np.pi, diff))


def _scale_error(gt: BoxSequence, pred: BoxSequence, f: np.ndarray, g: np.ndarray, p: np.ndarray) -> np.ndarray:
    gt_size = np.stack([gt.width[f, g], gt.length[f, g], gt.height[f, g]])
    pred_size = np.stack([pred.width[f, p], pred.length[f, p], pred.height[f, p]])
    inter = np.prod(np.minimum(gt_size, pred_size), axis=0)
    union = np.prod(gt_size, axis=0) + np.prod(pred_size, axis=0) - inter
    return 1.0 - inter / union


def nds(gt: BoxSequence, pred: BoxSequence, ego_xy: np.ndarray) -> NDSResult:
    """NDS of predictions against ground truth over a sequence; ego_xy (F, 2) sets the range."""
    gt_ok = in_range(gt, ego_xy)
    pred_ok = in_range(pred, ego_xy)
    npos = int(gt_ok.sum())
    dist = np.hypot(pred.x[:, :, None] - gt.x[:, None, :], pred.y[:, :, None] - gt.y[:, None, :])
    order = _prediction_order(pred.score, pred_ok)
    matchings = greedy_match(dist, order, pred_ok, gt_ok, DIST_THRESHOLDS)

    # global order of the devkit: descending score, ties by descending position in the flat list
    pf, pp = np.nonzero(pred_ok)
    flat_scores = pred.score[pf, pp]
    glob = np.lexsort((-np.arange(pf.size), -flat_scores))
    pf, pp, conf = pf[glob], pp[glob], flat_scores[glob]
    rec_interp = np.linspace(0.0, 1.0, NUM_POINTS)

    ap: dict[float, float] = {}
    tp_errors = {name: 1.0 for name in TP_METRICS}
    for th, matching in matchings.items():
        matched_gt = matching.pred_gt[pf, pp]
        is_tp = matched_gt >= 0
        if npos == 0 or not is_tp.any():
            ap[th] = 0.0
            continue
        tp = np.cumsum(is_tp).astype(float)
        fp = np.cumsum(~is_tp).astype(float)
        prec = np.interp(rec_interp, tp / npos, tp / (fp + tp), right=0)
        conf_interp = np.interp(rec_interp, tp / npos, conf, right=0)
        useful = prec[FIRST_USEFUL:] - MIN_PRECISION
        useful[useful < 0] = 0
        ap[th] = float(np.mean(useful)) / (1.0 - MIN_PRECISION)
        if th != TP_THRESHOLD:
            continue
        f, p, g = pf[is_tp], pp[is_tp], matched_gt[is_tp]
        errors = np.stack([
            np.hypot(pred.x[f, p] - gt.x[f, g], pred.y[f, p] - gt.y[f, g]),
            _scale_error(gt, pred, f, g, p),
            _angle_diff(gt.yaw[f, g], pred.yaw[f, p]),
            np.hypot(pred.vx[f, p] - gt.vx[f, g], pred.vy[f, p] - gt.vy[f, g]),
        ])  # in TP_METRICS order; attributes always agree, so attr_err is 0 wherever it is defined
        # the devkit's cummean (nancumsum / count); inputs are validated finite, so no NaN to skip
        running_mean = np.cumsum(errors, axis=1) / np.arange(1, f.size + 1)
        match_conf = conf[is_tp][::-1]
        nonzero = np.nonzero(conf_interp)[0]
        last = int(nonzero[-1]) if nonzero.size else 0
        if last >= FIRST_USEFUL:
            for name, curve_at_matches in zip(TP_METRICS, running_mean):
                curve = np.interp(conf_interp[::-1], match_conf, curve_at_matches[::-1])[::-1]
                tp_errors[name] = float(np.mean(curve[FIRST_USEFUL : last + 1]))
            tp_errors["attr_err"] = 0.0

    mean_ap = float(np.mean([ap[th] for th in DIST_THRESHOLDS]))
    tp_score = sum(max(0.0, 1.0 - tp_errors[name]) for name in TP_METRICS)
    score = (MEAN_AP_WEIGHT * mean_ap + tp_score) / (MEAN_AP_WEIGHT + len(TP_METRICS))
    return NDSResult(
        nds=float(score),
        mean_ap=mean_ap,
        ap=ap,
        tp_errors=tp_errors,
        matchings=matchings,
        gt_in_range=gt_ok,
        pred_in_range=pred_ok,
    )
