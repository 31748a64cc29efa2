"""nuScenes detection score for the class car, as nuscenes-devkit 1.2.0 computes it, vectorised.

Config detection_cvpr_2019 restricted to cars: match thresholds 0.5/1/2/4 m on centre distance,
TP metrics at 2 m, class range 50 m around the ego (strict <, for truth and predictions alike),
greedy matching in descending confidence with strict <, 101-point interpolation, recall and
precision floors 0.1, AAE = 0 (truth and predictions share one attribute). Each frame is a sample.

The devkit matches predictions one by one in a Python loop. Here, since a prediction only
competes with predictions of its own frame, every frame is matched at once: where no two
predictions of a frame want the same gt, each takes its nearest; the few frames where two do run
the devkit's loop, rank by rank, all together.
"""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.boxes import BoxSequence, in_range

DIST_THRESHOLDS = (0.5, 1.0, 2.0, 4.0)
TP_THRESHOLD = 2.0
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
    """The nuScenes detection score of a sequence and what it was computed from: the matchings are
    kept because NDS-t and the TP/FN counts reuse them instead of matching again."""

    nds: float
    mean_ap: float
    ap: dict[float, float]
    tp_errors: dict[str, float]
    matchings: dict[float, Matching]  # per distance threshold, reused by NDS-t and the counts
    gt_in_range: np.ndarray  # (F, G) bool
    pred_in_range: np.ndarray  # (F, P) bool


def _prediction_order(scores: np.ndarray) -> np.ndarray:
    """Per frame, prediction slots by descending confidence; ties by descending slot (the devkit
    sorts (score, index) pairs and reverses); absent slots (nan) last."""
    slots = np.broadcast_to(np.arange(scores.shape[1]), scores.shape)
    return np.lexsort((-slots, -scores), axis=-1)


def _nearest(dist: np.ndarray, limit: float) -> tuple[np.ndarray, np.ndarray]:
    """Along axis 1 of dist (n, G, m): the smallest value, and a one-hot (n, G, m) of the first
    index holding it where that value is below limit (argmin is slow along a short axis)."""
    nearest = dist.min(axis=1)
    near = nearest < limit
    first = (dist == nearest[:, None]) & near[:, None]
    if np.count_nonzero(first) > np.count_nonzero(near):  # equally near: the first, as argmin
        first &= np.cumsum(first, axis=1) == 1
    return nearest, first


def _index(one_hot: np.ndarray) -> np.ndarray:
    """The index along axis 1 of a one-hot (n, G, m); 0 where it holds no True."""
    return np.matmul(np.arange(one_hot.shape[1], dtype=float), one_hot).astype(np.int64)


def _greedy_by_rank(ranked_dist: np.ndarray, below: np.ndarray) -> np.ndarray:
    """The devkit's loop, one confidence rank at a time, for all frames and thresholds at once.

    ranked_dist (P, G, F) from each frame's rank-r prediction (inf: may not match); below (H, 1)
    the thresholds. Returns the matched gt (H, P, F), -1 if none.
    """
    num_pred, num_gt, num_frames = ranked_dist.shape
    shape = (1, num_gt, len(below) * num_frames)  # thresholds and frames on one axis
    free = np.ones(shape, dtype=bool)
    out = np.full((num_pred, len(below), num_frames), -1)
    for rank in range(num_pred):
        d = np.broadcast_to(ranked_dist[rank, :, None, :], (num_gt, len(below), num_frames)).reshape(shape)
        nearest, take = _nearest(np.where(free, d, np.inf), np.inf)
        hit = nearest.reshape(len(below), num_frames) < below
        take &= hit.reshape(1, 1, -1)
        out[rank] = np.where(hit, _index(take).reshape(hit.shape), -1)
        free ^= take  # take is within free
    return out.transpose(1, 0, 2)


def greedy_match(dist: np.ndarray, scores: np.ndarray, thresholds: tuple[float, ...]) -> np.ndarray:
    """The devkit's greedy matching for every threshold at once.

    dist (P, G, F) centre distances by prediction slot, inf where the pair may not match (either
    box out of range: such a prediction takes nothing wherever it ranks); scores (F, P). In
    descending confidence, each prediction takes the nearest untaken gt (first index on ties, as
    the devkit's strict <) and is a match if that distance is below the threshold. Returns the
    matched gt of each prediction slot (H, P, F), -1 if none.

    Where no two predictions of a frame have the same nearest gt within the loosest threshold, no
    prediction finds its nearest gt taken, so each simply takes its nearest: that is all frames
    at once. Frames where two do go through the devkit's loop, rank by rank. Axes put the frames
    last: numpy reduces over a short last axis slowly.
    """
    num_pred, num_gt, num_frames = dist.shape
    below = np.asarray(thresholds)[:, None]
    if num_pred == 0 or num_gt == 0:
        return np.full((len(thresholds), num_pred, num_frames), -1)
    nearest, first = _nearest(dist, max(thresholds))  # (P, F), (P, G, F)
    matched = np.where(nearest < below[:, :, None], _index(first), -1)  # (H, P, F)
    contested = np.flatnonzero((np.count_nonzero(first, axis=0) > 1).any(axis=0))
    if contested.size:
        ranked = _prediction_order(scores[contested]).T  # (P, C)
        by_rank = _greedy_by_rank(dist[ranked[:, None, :], np.arange(num_gt)[:, None], contested], below)
        matched[:, ranked, contested] = by_rank
    return matched


def _angle_diff(a_minus_b: np.ndarray) -> np.ndarray:
    """The devkit's |angle_diff(a, b)| from a - b."""
    diff = (a_minus_b + np.pi) % (2.0 * np.pi) - np.pi
    return np.abs(np.where(diff > np.pi, diff - 2.0 * np.pi, diff))


def _mean(values: np.ndarray) -> np.floating:
    """np.mean without its Python wrapper (the same sum and division), which here costs more than the sum."""
    return values.sum() / values.size


_REC_INTERP = np.linspace(0.0, 1.0, NUM_POINTS)
# what the TP metrics read of a box, sizes in the devkit's wlh order
_TP_FIELDS = ("x", "y", "vx", "vy", "yaw", "width", "length", "height")


def nds_score(mean_ap: float, tp_score: float) -> float:
    """NDS from the mean AP and the TP metrics' summed scores (each 1 - min(1, error))."""
    return (MEAN_AP_WEIGHT * mean_ap + tp_score) / (MEAN_AP_WEIGHT + len(TP_METRICS))


def ap_bound(max_recall: float) -> float:
    """The largest AP `nds` can give when recall cannot pass `max_recall` (some truth no detection
    matches): precision at most 1 at the interpolation points up to it and 0 beyond, less the
    precision floor. Equal when no false positive ranks above a true one."""
    useful = _REC_INTERP[FIRST_USEFUL:]
    return float((useful <= max_recall + 1e-12).sum()) / useful.size


def _gather(boxes: BoxSequence, frames: np.ndarray, slots: np.ndarray) -> np.ndarray:
    """_TP_FIELDS (8, n) of the (frame, slot) boxes, by flat index (np.take on 1-D is cheap)."""
    flat = frames * boxes.shape[1] + slots
    return np.array([np.take(getattr(boxes, name), flat) for name in _TP_FIELDS])


def _tp_errors(
    gt: BoxSequence, pred: BoxSequence, frames: np.ndarray, slots: np.ndarray, gts: np.ndarray,
    match_conf: np.ndarray, conf_interp: np.ndarray, last: int,
) -> dict[str, float]:
    """The devkit's TP metrics from the true positives (frames, pred slots, gt slots) in global order.

    Attributes always agree, so attr_err is 0 wherever it is defined.
    """
    g, p = _gather(gt, frames, gts), _gather(pred, frames, slots)
    diff = g - p
    errors = np.empty((4, len(frames)))  # TP_METRICS but attr_err
    errors[0:4:3] = np.hypot(diff[0:4:2], diff[1:4:2])  # centre and velocity
    inter = np.minimum(g[5], p[5]) * np.minimum(g[6], p[6]) * np.minimum(g[7], p[7])
    errors[1] = 1.0 - inter / (g[5] * g[6] * g[7] + p[5] * p[6] * p[7] - inter)  # 1 - IoU aligned and centred
    errors[2] = _angle_diff(diff[4])
    # the devkit's cummean (nancumsum / count); inputs are validated finite, so no NaN to skip
    running_mean = np.cumsum(errors, axis=1) / np.arange(1, errors.shape[1] + 1)
    out = {}
    for name, curve_at_matches in zip(TP_METRICS, running_mean):
        curve = np.interp(conf_interp[::-1], match_conf[::-1], curve_at_matches[::-1])[::-1]
        out[name] = float(_mean(curve[FIRST_USEFUL : last + 1]))
    out["attr_err"] = 0.0
    return out


def nds(gt: BoxSequence, pred: BoxSequence, ego_xy: np.ndarray) -> NDSResult:
    """NDS of predictions against ground truth over a sequence; ego_xy (F, 2) sets the range."""
    gt_ok = in_range(gt, ego_xy)
    pred_ok = in_range(pred, ego_xy)
    npos = int(gt_ok.sum())
    # (slot, frame) layouts from here: numpy reduces and broadcasts faster with the frames last
    pairs = np.ascontiguousarray(pred_ok.T)[:, None, :] & np.ascontiguousarray(gt_ok.T)  # (P, G, F)
    dist = np.full(pairs.shape, np.inf)  # only pairs in range can match
    dx = np.ascontiguousarray(pred.x.T)[:, None, :] - np.ascontiguousarray(gt.x.T)
    dy = np.ascontiguousarray(pred.y.T)[:, None, :] - np.ascontiguousarray(gt.y.T)
    np.hypot(dx, dy, out=dist, where=pairs)
    matched = greedy_match(dist, pred.score, DIST_THRESHOLDS)  # (H, P, F)
    matchings = {th: Matching(pred_gt=matched[i].T) for i, th in enumerate(DIST_THRESHOLDS)}

    # global order of the devkit: descending score, ties by descending position in the flat list
    pf, pp = np.nonzero(pred_ok)
    flat_scores = pred.score[pf, pp]
    glob = np.lexsort((-np.arange(pf.size), -flat_scores))
    pf, pp, conf = pf[glob], pp[glob], flat_scores[glob]
    matched_gt = matched[:, pp, pf]  # (H, M)
    is_tp = matched_gt >= 0
    tp = np.cumsum(is_tp, axis=1, dtype=float)
    recall = tp / max(npos, 1)  # unused without positives
    precision = tp / np.arange(1, pf.size + 1)  # tp + fp is the rank

    ap: dict[float, float] = {}
    tp_errors = dict.fromkeys(TP_METRICS, 1.0)
    for i, th in enumerate(DIST_THRESHOLDS):
        if npos == 0 or not is_tp[i].any():
            ap[th] = 0.0
            continue
        prec = np.interp(_REC_INTERP, recall[i], precision[i], right=0)
        useful = prec[FIRST_USEFUL:] - MIN_PRECISION
        useful[useful < 0] = 0
        ap[th] = float(_mean(useful)) / (1.0 - MIN_PRECISION)
        if th != TP_THRESHOLD:
            continue
        conf_interp = np.interp(_REC_INTERP, recall[i], conf, right=0)
        nonzero = np.flatnonzero(conf_interp)
        last = int(nonzero[-1]) if nonzero.size else 0
        if last >= FIRST_USEFUL:
            hits = is_tp[i]
            tp_errors = _tp_errors(gt, pred, pf[hits], pp[hits], matched_gt[i, hits], conf[hits], conf_interp, last)

    mean_ap = float(np.mean([ap[th] for th in DIST_THRESHOLDS]))
    tp_score = sum(max(0.0, 1.0 - tp_errors[name]) for name in TP_METRICS)
    return NDSResult(
        nds=float(nds_score(mean_ap, tp_score)),
        mean_ap=mean_ap,
        ap=ap,
        tp_errors=tp_errors,
        matchings=matchings,
        gt_in_range=gt_ok,
        pred_in_range=pred_ok,
    )
