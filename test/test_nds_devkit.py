"""Our NDS against nuscenes-devkit 1.2.0 itself, on committed randomised cases.

The devkit pins numpy<2, so it cannot share this environment: test/fixtures/nds/make_devkit_fixtures.py
runs it from its own venv (see that script's docstring) and stored its answers in devkit_cases.json.
"""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.metrics.nds import DIST_THRESHOLDS, greedy_match, nds

CASES = json.loads((Path(__file__).parent / "fixtures" / "nds" / "devkit_cases.json").read_text())
COLUMNS = ("ids", "x", "y", "yaw", "length", "width", "height", "vx", "vy")


def _boxes(frames: list[list[list[float]]], with_score: bool) -> BoxSequence:
    rows = []
    for boxes in frames:
        arr = np.asarray(boxes, dtype=float).reshape(-1, len(COLUMNS) + with_score)
        frame = {name: arr[:, i] for i, name in enumerate(COLUMNS)}
        frame["ids"] = frame["ids"].astype(np.int64)
        if with_score:
            frame["score"] = arr[:, -1]
        rows.append(frame)
    return BoxSequence.stack(rows)


def case_inputs(case: dict) -> tuple[BoxSequence, BoxSequence, np.ndarray]:
    frames = case["frames"]
    gt = _boxes([f["gt"] for f in frames], with_score=False)
    pred = _boxes([f["pred"] for f in frames], with_score=True)
    ego = np.array([f["ego"] for f in frames], dtype=float)
    return gt, pred, ego


def test_fixtures_cover_the_required_variety():
    assert len(CASES) >= 20
    assert len({round(c["devkit"]["nds"], 6) for c in CASES}) >= 20


@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
def test_nds_equals_devkit(case):
    gt, pred, ego = case_inputs(case)
    ours = nds(gt, pred, ego)
    ref = case["devkit"]
    assert ours.nds == pytest.approx(ref["nds"], abs=1e-9)
    assert ours.mean_ap == pytest.approx(ref["map"], abs=1e-9)
    for th in DIST_THRESHOLDS:
        assert ours.ap[th] == pytest.approx(ref["ap"][f"{th:.1f}"], abs=1e-9), th
    for name, value in ref["tp_errors"].items():
        expected = math.nan if value is None else value
        assert ours.tp_errors[name] == pytest.approx(expected, abs=1e-9, nan_ok=True), name


def devkit_loop(dist, scores, threshold):
    """The devkit's accumulate() matching, frame by frame: predictions by descending (score, index),
    each taking the nearest untaken gt (strict <, so the first of equals) if nearer than the threshold."""
    num_frames, num_pred, num_gt = dist.shape
    out = np.full((num_frames, num_pred), -1)
    for f in range(num_frames):
        taken = set()
        present = [i for i in range(num_pred) if np.isfinite(scores[f, i])]
        for p in sorted(present, key=lambda i: (scores[f, i], i), reverse=True):
            best, best_g = np.inf, None
            for g in range(num_gt):
                if g not in taken and dist[f, p, g] < best:
                    best, best_g = dist[f, p, g], g
            if best_g is not None and best < threshold:
                taken.add(best_g)
                out[f, p] = best_g
    return out


@pytest.mark.parametrize("seed", range(4))
def test_greedy_match_equals_the_devkit_loop(seed):
    """Random frames where predictions compete for gts and distances and scores tie exactly,
    including pairs that may not match (inf) and absent predictions (nan score)."""
    rng = np.random.default_rng(seed)
    num_frames, num_pred, num_gt = 300, rng.integers(1, 7), rng.integers(1, 7)
    dist = rng.choice([0.3, 0.5, 0.7, 1.0, 1.5, 2.0, 3.0, 4.0, 5.0, np.inf], size=(num_frames, num_pred, num_gt))
    dist[::2] = rng.uniform(0.0, 5.0, size=dist[::2].shape)
    scores = rng.choice([0.2, 0.5, 0.9, np.nan], size=(num_frames, num_pred))
    dist[np.isnan(scores)] = np.inf
    got = greedy_match(np.ascontiguousarray(dist.transpose(1, 2, 0)), scores, DIST_THRESHOLDS)
    for i, th in enumerate(DIST_THRESHOLDS):
        np.testing.assert_array_equal(got[i].T, devkit_loop(dist, scores, th), err_msg=f"threshold {th}")
