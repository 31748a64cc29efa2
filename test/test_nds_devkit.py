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
from advperc_ros.core.metrics.nds import DIST_THRESHOLDS, nds

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
