"""Perception scores: longest drop fraction, NDS-t, Table 1 counts, confidences."""

import math

import numpy as np
import pytest

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.perception_errors import PerceptionErrors, confidence_scores, inject
from advperc_ros.core.metrics.nds import ap_bound, nds
from advperc_ros.core.metrics.scores import longest_drop_fraction, score

# ---------------------------------------------------------------- longest drop fraction


def naive_ldf(missed, counted):
    worst = 0.0
    num_frames, num_agents = missed.shape
    for j in range(num_agents):
        seq = [bool(missed[k, j]) for k in range(num_frames) if counted[k, j]]
        if not seq:
            continue
        best = run = 0
        for m in seq:
            run = run + 1 if m else 0
            best = max(best, run)
        worst = max(worst, best / len(seq))
    return worst


@pytest.mark.parametrize("seed", range(5))
def test_longest_drop_fraction_matches_naive_reference(seed):
    rng = np.random.default_rng(seed)
    for _ in range(60):
        frames, agents = rng.integers(1, 30), rng.integers(1, 6)
        counted = rng.random((frames, agents)) < rng.uniform(0.3, 1.0)
        missed = counted & (rng.random((frames, agents)) < rng.uniform(0.0, 1.0))
        # sometimes agents are absent in the middle: runs are over the frames that count
        assert longest_drop_fraction(missed, counted) == pytest.approx(naive_ldf(missed, counted), abs=1e-15)


def test_longest_drop_fraction_hand_cases():
    counted = np.ones((10, 2), dtype=bool)
    missed = np.zeros((10, 2), dtype=bool)
    assert longest_drop_fraction(missed, counted) == 0.0
    missed[2:5, 0] = True
    missed[[0, 2, 4, 6], 1] = True
    assert longest_drop_fraction(missed, counted) == pytest.approx(0.3)
    # frames where agent 0 does not count are skipped: the runs 2..4 and 6..7 join
    counted[5, 0] = False
    missed[6:8, 0] = True
    assert longest_drop_fraction(missed, counted) == pytest.approx(5 / 9)
    assert longest_drop_fraction(np.zeros((0, 0), bool), np.zeros((0, 0), bool)) == 0.0


# ---------------------------------------------------------------- random sequences


def random_case(rng, frames=None, agents=None, extra=None):
    """Ground truth with agents moving near a moving ego (some beyond 50 m), and predictions derived from
    it with offsets, drops, out-of-range moves, and false positives in extra slots. Scores strictly
    distinct."""
    frames = frames or int(rng.integers(2, 12))
    agents = agents or int(rng.integers(1, 7))
    extra = int(rng.integers(0, 4)) if extra is None else extra
    ego = np.stack([np.linspace(0, 20, frames), np.zeros(frames)], axis=1) + rng.normal(0, 1, (frames, 2))
    gt = BoxSequence.empty(frames, agents)
    start = rng.uniform(-60, 60, (1, agents, 2)) + ego[:1, None, :]
    vel = rng.uniform(-8, 8, (1, agents, 2))
    pos = start + vel * (0.1 * np.arange(frames))[:, None, None]
    # a few agents sit right at the range boundary
    near_edge = rng.random(agents) < 0.3
    if near_edge.any():
        ang = rng.uniform(0, 2 * np.pi, near_edge.sum())
        radius = rng.choice([49.9, 50.0, 50.1], near_edge.sum())
        pos[:, near_edge, 0] = ego[:, :1] + radius * np.cos(ang)
        pos[:, near_edge, 1] = ego[:, 1:] + radius * np.sin(ang)
    gt.ids[:] = np.arange(1, agents + 1)
    gt.valid[:] = rng.random((frames, agents)) < 0.9
    gt.x[:], gt.y[:] = pos[..., 0], pos[..., 1]
    gt.yaw[:] = rng.uniform(-np.pi, np.pi, (frames, agents))
    gt.vx[:], gt.vy[:] = vel[..., 0], vel[..., 1]
    gt.length[:], gt.width[:], gt.height[:] = 4.5, 1.9, 1.6
    slots = agents + extra
    pred = BoxSequence.empty(frames, slots)
    for name in ("ids", "valid", "x", "y", "yaw", "vx", "vy", "length", "width", "height"):
        getattr(pred, name)[:, :agents] = getattr(gt, name)
    kind = rng.integers(0, 5, (frames, agents))
    noise = rng.normal(0, 1, (frames, agents, 2))
    scale = np.choose(kind, [0.1, 0.8, 2.0, 4.5, 0.0])  # small, medium, large, beyond 4 m, exact
    pred.x[:, :agents] += noise[..., 0] * scale
    pred.y[:, :agents] += noise[..., 1] * scale
    pred.yaw[:, :agents] += rng.normal(0, 0.3, (frames, agents))
    pred.valid[:, :agents] &= rng.random((frames, agents)) < 0.8
    # false positives: near some agent (competing for it) or anywhere
    if extra:
        anchor = rng.integers(0, agents, (frames, extra))
        pred.x[:, agents:] = gt.x[np.arange(frames)[:, None], anchor] + rng.normal(0, 2, (frames, extra))
        pred.y[:, agents:] = gt.y[np.arange(frames)[:, None], anchor] + rng.normal(0, 2, (frames, extra))
        pred.yaw[:, agents:] = rng.uniform(-np.pi, np.pi, (frames, extra))
        pred.valid[:, agents:] = rng.random((frames, extra)) < 0.7
        pred.length[:, agents:], pred.width[:, agents:], pred.height[:, agents:] = 4.5, 1.9, 1.6
    pred.score[:] = (rng.permutation(frames * slots) + 1.0).reshape(frames, slots) / (frames * slots + 1.0)
    return gt, pred, ego


def devkit_counts(gt, pred, ego, th=4.0):
    """Naive re-implementation of the devkit's greedy matching per sample, and the Table 1 columns."""
    frames = gt.shape[0]
    tp = fn = fp = 0
    pos_err, ori_err = [], []
    matched_by_frame = []
    for k in range(frames):
        gts = [g for g in range(gt.shape[1])
               if gt.valid[k, g] and math.hypot(gt.x[k, g] - ego[k, 0], gt.y[k, g] - ego[k, 1]) < 50.0]
        preds = [p for p in range(pred.shape[1])
                 if pred.valid[k, p] and math.hypot(pred.x[k, p] - ego[k, 0], pred.y[k, p] - ego[k, 1]) < 50.0]
        preds.sort(key=lambda p: -pred.score[k, p])
        taken = set()
        matched = set()
        for p in preds:
            best, match = math.inf, None
            for g in gts:
                if g in taken:
                    continue
                d = math.hypot(pred.x[k, p] - gt.x[k, g], pred.y[k, p] - gt.y[k, g])
                if d < best:
                    best, match = d, g
            if match is not None and best < th:
                taken.add(match)
                matched.add(match)
                tp += 1
                pos_err.append(best)
                diff = (pred.yaw[k, p] - gt.yaw[k, match] + math.pi) % (2 * math.pi) - math.pi
                ori_err.append(abs(diff))
            else:
                fp += 1
        fn += len(gts) - len(matched)
        matched_by_frame.append(matched)
    mpe = float(np.mean(pos_err)) if pos_err else float("nan")
    maoe = float(np.mean(ori_err)) if ori_err else float("nan")
    return tp, fn, fp, mpe, maoe, matched_by_frame


@pytest.mark.parametrize("seed", range(40))
def test_counts_match_naive_devkit_matching(seed):
    rng = np.random.default_rng(1000 + seed)
    gt, pred, ego = random_case(rng)
    got = score(gt, pred, ego)
    tp, fn, fp, mpe, maoe, matched = devkit_counts(gt, pred, ego)
    assert (got.tp, got.fn, got.fp) == (tp, fn, fp)
    if tp:
        assert got.mpe == pytest.approx(mpe, rel=1e-12)
        assert got.maoe == pytest.approx(maoe, rel=1e-12, abs=1e-15)
    else:
        assert math.isnan(got.mpe) and math.isnan(got.maoe)
    # NDS-t from the same matching: the missed object-frames are the counted ones left unmatched
    counted = np.zeros(gt.shape, bool)
    missed = np.zeros(gt.shape, bool)
    for k in range(gt.shape[0]):
        for g in range(gt.shape[1]):
            counted[k, g] = gt.valid[k, g] and math.hypot(gt.x[k, g] - ego[k, 0], gt.y[k, g] - ego[k, 1]) < 50.0
            missed[k, g] = counted[k, g] and g not in matched[k]
    ldf = naive_ldf(missed, counted)
    assert got.longest_drop_fraction == pytest.approx(ldf, abs=1e-15)
    assert got.nds_t == pytest.approx((got.nds + 1.0 - ldf) / 2.0, abs=1e-15)
    assert got.nds == pytest.approx(nds(gt, pred, ego).nds, abs=1e-15)
    assert 0.0 <= got.nds <= 1.0 and 0.0 <= got.nds_t <= 1.0


def test_range_is_strict_for_truth_and_predictions():
    ego = np.zeros((1, 2))
    gt = BoxSequence.stack([{"ids": np.array([1, 2]), "x": np.array([49.999, 50.0]), "y": np.zeros(2),
                             "length": np.full(2, 4.5), "width": np.full(2, 1.9), "height": np.full(2, 1.6)}])
    pred = BoxSequence.stack([{"ids": np.array([1, 2, 3]), "x": np.array([49.999, 50.0, 51.0]), "y": np.zeros(3),
                               "length": np.full(3, 4.5), "width": np.full(3, 1.9), "height": np.full(3, 1.6),
                               "score": np.array([0.9, 0.8, 0.7])}])
    got = score(gt, pred, ego)
    # the box at exactly 50 m counts for neither side
    assert (got.tp, got.fn, got.fp) == (1, 0, 0)


def test_match_threshold_is_strict_at_four_metres():
    ego = np.zeros((1, 2))
    gt = BoxSequence.stack([{"ids": np.array([1]), "x": np.array([10.0]), "y": np.zeros(1),
                             "length": np.full(1, 4.5), "width": np.full(1, 1.9), "height": np.full(1, 1.6)}])

    def pred_at(x):
        return BoxSequence.stack([{"ids": np.array([1]), "x": np.array([x]), "y": np.zeros(1),
                                   "length": np.full(1, 4.5), "width": np.full(1, 1.9), "height": np.full(1, 1.6),
                                   "score": np.array([0.5])}])

    assert (score(gt, pred_at(14.0), ego).tp, score(gt, pred_at(14.0), ego).fn) == (0, 1)
    assert score(gt, pred_at(14.0), ego).fp == 1
    assert (score(gt, pred_at(13.99), ego).tp, score(gt, pred_at(13.99), ego).fn) == (1, 0)
    assert score(gt, pred_at(13.99), ego).mpe == pytest.approx(3.99)


def test_greedy_confidence_order_decides_who_matches():
    """Two predictions near one object: the more confident one takes it even if it is farther."""
    ego = np.zeros((1, 2))
    gt = BoxSequence.stack([{"ids": np.array([1]), "x": np.array([10.0]), "y": np.zeros(1),
                             "length": np.full(1, 4.5), "width": np.full(1, 1.9), "height": np.full(1, 1.6)}])
    pred = BoxSequence.stack([{"ids": np.array([1, 2]), "x": np.array([10.1, 13.0]), "y": np.zeros(2),
                               "length": np.full(2, 4.5), "width": np.full(2, 1.9), "height": np.full(2, 1.6),
                               "score": np.array([0.3, 0.9])}])
    got = score(gt, pred, ego)
    assert (got.tp, got.fn, got.fp) == (1, 0, 1)
    assert got.mpe == pytest.approx(3.0)


# ---------------------------------------------------------------- perfect perception and attacks


def scenario_like_truth(frames=40, agents=4, seed=0):
    rng = np.random.default_rng(seed)
    gt = BoxSequence.empty(frames, agents)
    t = 0.1 * np.arange(frames)[:, None]
    gt.ids[:] = np.arange(1, agents + 1)
    gt.valid[:] = True
    gt.x[:] = rng.uniform(5, 30, agents) + rng.uniform(-3, 3, agents) * t  # stays within 50 m
    gt.y[:] = rng.uniform(-6, 6, agents)
    gt.yaw[:] = rng.uniform(-np.pi, np.pi, agents)
    gt.vx[:] = 1.0
    gt.length[:], gt.width[:], gt.height[:] = 4.5, 1.9, 1.6
    return gt


def test_perfect_perception():
    gt = scenario_like_truth()
    ego = np.zeros((gt.shape[0], 2))
    got = score(gt, inject(gt, PerceptionErrors.none(*gt.shape)), ego)
    assert got.nds == pytest.approx(1.0, abs=1e-9)
    assert got.mean_ap == pytest.approx(1.0, abs=1e-9)
    assert got.nds_t == pytest.approx(1.0, abs=1e-9)
    assert got.longest_drop_fraction == 0.0
    assert (got.tp, got.fn, got.fp) == (gt.valid.sum(), 0, 0)
    assert got.mpe == 0.0 and got.maoe == 0.0
    assert set(got.as_dict()) == {
        "nds", "nds_t", "longest_drop_fraction", "mean_ap", "tp", "fn", "fp", "mpe", "maoe", "pem_ll"
    }


def test_dropping_an_agent_lowers_nds_t_through_its_run():
    gt = scenario_like_truth()
    ego = np.zeros((gt.shape[0], 2))
    errors = PerceptionErrors.none(*gt.shape).with_drop(2, 10, 29)
    got = score(gt, inject(gt, errors), ego)
    assert got.fn == 20
    assert got.longest_drop_fraction == pytest.approx(20 / 40)
    assert got.nds_t == pytest.approx((got.nds + 0.5) / 2)
    assert got.nds < 1.0


def test_offset_within_four_metres_is_not_a_drop():
    gt = scenario_like_truth()
    ego = np.zeros((gt.shape[0], 2))
    errors = PerceptionErrors.none(*gt.shape)
    errors.dx[5:15, 1] = 3.0
    got = score(gt, inject(gt, errors), ego)
    assert got.fn == 0 and got.fp == 0
    assert got.longest_drop_fraction == 0.0
    assert got.mpe == pytest.approx(3.0 * 10 / gt.valid.sum())
    errors.dx[5:15, 1] = 4.5  # beyond every threshold: a false negative and a false positive per frame
    got = score(gt, inject(gt, errors), ego)
    assert (got.fn, got.fp) == (10, 10)
    assert got.longest_drop_fraction == pytest.approx(10 / 40)


# ---------------------------------------------------------------- confidences


@pytest.mark.parametrize("shape", [(1, 1), (3, 7), (100, 5), (465, 1)])
def test_confidence_scores_distinct_in_open_unit_interval_and_reproducible(shape):
    scores = confidence_scores(*shape)
    assert scores.shape == shape
    assert np.unique(scores).size == scores.size
    assert np.all(scores > 0.0) and np.all(scores < 1.0)
    again = confidence_scores(*shape)
    np.testing.assert_array_equal(scores, again)
    confidence_scores.cache_clear()
    np.testing.assert_array_equal(scores, confidence_scores(*shape))  # not merely the cached object
    with pytest.raises(ValueError):
        scores[0, 0] = 0.5  # read-only: a caller cannot corrupt the cache


def test_confidences_are_not_ordered_by_frame_or_agent():
    scores = confidence_scores(50, 4)
    # a permutation, not a monotone pattern an attack could use
    assert not np.all(np.diff(scores.ravel()) > 0)
    assert not np.all(np.diff(scores.ravel()) < 0)


def test_ap_bound_is_reached_by_a_drop_and_never_passed():
    """ap_bound (the premise of benchmarks/right_turn_sightings.py): hiding one car throughout caps
    recall, and with no false positive AP is exactly the bound at every threshold; shown displaced
    instead (a false positive at the tighter thresholds), AP stays at or under it."""
    gt = scenario_like_truth(agents=5, seed=3)
    gt.y[:] = 10.0 * np.arange(5) - 20.0  # 10 m apart: no car's detection comes within 4 m of another car
    frames, agents = gt.shape
    ego = np.zeros((frames, 2))
    errors = PerceptionErrors.none(frames, agents)
    errors.fn[:, 2] = True
    result = nds(gt, inject(gt, errors), ego)
    recall = 1.0 - result.gt_in_range[:, 2].sum() / result.gt_in_range.sum()
    assert all(ap == pytest.approx(ap_bound(recall), abs=1e-12) for ap in result.ap.values())
    for offset in (0.7, 1.5, 3.0):
        shown = PerceptionErrors.none(frames, agents)
        shown.dx[:, 2] = offset
        tight = nds(gt, inject(gt, shown), ego).ap
        assert all(tight[th] <= ap_bound(recall) + 1e-12 for th in tight if th <= offset)
