"""What `matched_errors` reads back for the perception error model beyond the paper's errors: the
velocity errors and size scales of the matches, and the false positives per frame, against a naive
re-implementation of the devkit's greedy matching at 4 m."""

import math

import numpy as np
import pytest
from test_scores import random_case

from advperc_ros.core.metrics.scores import matched_errors, score


def naive_matches(gt, pred, ego, threshold=4.0):
    """Per frame: {gt slot: pred slot} of the greedy matching, and the in-range unmatched pred slots."""
    def near(boxes, k, i):
        return boxes.valid[k, i] and math.hypot(boxes.x[k, i] - ego[k, 0], boxes.y[k, i] - ego[k, 1]) < 50.0

    frames = []
    for k in range(gt.shape[0]):
        gts = [g for g in range(gt.shape[1]) if near(gt, k, g)]
        preds = sorted((p for p in range(pred.shape[1]) if near(pred, k, p)), key=lambda p: -pred.score[k, p])
        pairs, unmatched = {}, []
        for p in preds:
            free = [g for g in gts if g not in pairs]
            best = min(free, key=lambda g: math.hypot(pred.x[k, p] - gt.x[k, g], pred.y[k, p] - gt.y[k, g]),
                       default=None)
            if best is not None and math.hypot(pred.x[k, p] - gt.x[k, best], pred.y[k, p] - gt.y[k, best]) < threshold:
                pairs[best] = p
            else:
                unmatched.append(p)
        frames.append((pairs, unmatched))
    return frames


@pytest.mark.parametrize("seed", range(20))
def test_velocity_size_and_false_positives_are_read_off_the_matching(seed):
    rng = np.random.default_rng(500 + seed)
    gt, pred, ego = random_case(rng)
    pred.vx[:] += rng.normal(0.0, 1.0, pred.shape)
    pred.vy[:] += rng.normal(0.0, 1.0, pred.shape)
    pred.length[:] *= rng.uniform(0.7, 1.4, pred.shape)
    pred.width[:] *= rng.uniform(0.7, 1.4, pred.shape)
    errors, _, _ = matched_errors(gt, pred, ego)
    expected_ghosts = np.zeros(pred.shape, dtype=bool)
    for k, (pairs, unmatched) in enumerate(naive_matches(gt, pred, ego)):
        expected_ghosts[k, unmatched] = True
        for g in range(gt.shape[1]):
            p = pairs.get(g)
            assert errors.fn[k, g] == (p is None)
            want = (0.0, 0.0, 1.0, 1.0) if p is None else (
                pred.vx[k, p] - gt.vx[k, g], pred.vy[k, p] - gt.vy[k, g],
                pred.length[k, p] / gt.length[k, g], pred.width[k, p] / gt.width[k, g])
            got = (errors.dvx[k, g], errors.dvy[k, g], errors.length_scale[k, g], errors.width_scale[k, g])
            assert got == pytest.approx(want, rel=1e-12, abs=1e-15)
    assert np.array_equal(errors.ghost_on, expected_ghosts)
    assert np.array_equal(errors.ghost_x[errors.ghost_on], pred.x[errors.ghost_on])
    assert errors.ghost_on.sum() == score(gt, pred, ego).fp  # the false positives the report counts


def test_without_terms_beyond_the_paper_only_the_paper_errors_are_read():
    """What the hand-specified default scores: the same paper errors, nothing else to compute."""
    gt, pred, ego = random_case(np.random.default_rng(9))
    full, counted, _ = matched_errors(gt, pred, ego)
    paper, same, _ = matched_errors(gt, pred, ego, beyond_the_paper=False)
    assert paper.kinds == ("position", "yaw", "drop") and np.array_equal(counted, same)
    assert all(np.array_equal(getattr(paper, name), getattr(full, name)) for name in ("dx", "dy", "dyaw", "fn"))
