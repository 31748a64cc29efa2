"""nuScenes detection-results JSON (the devkit's submission format) as box sequences, for PEM fits.

Predictions: the devkit's results file, {"results": {sample_token: [box, ...]}}. Ground truth: the
same layout, as the devkit serialises its own DetectionBox objects (EvalBoxes.serialize()), which
carry `ego_translation` (box minus ego position) so the ego's position per sample is known. Only
boxes with detection_name "car" are read. Each sample becomes a frame; ground-truth slots are boxes
(a PEM is per object-frame and needs no identity across frames).
"""

import json
from pathlib import Path

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.exceptions import ScenarioError

CLASS = "car"


def _read(path: Path) -> dict[str, list[dict]]:
    try:
        document = json.loads(Path(path).read_text())
        results = document["results"] if "results" in document else document  # noqa: SIM401 -- the document may be a list
        if not isinstance(results, dict):
            raise TypeError("expected a mapping of sample tokens to box lists")
        return results
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ScenarioError(f"{path}: field 'results': not a nuScenes detection-results JSON: {exc}") from exc


def _frame(boxes: list[dict], path: Path, token: str, with_score: bool) -> dict[str, np.ndarray]:
    cars = [b for b in boxes if b.get("detection_name") == CLASS]
    try:
        xyz = np.array([b["translation"] for b in cars], dtype=float).reshape(-1, 3)
        wlh = np.array([b["size"] for b in cars], dtype=float).reshape(-1, 3)
        q = np.array([b["rotation"] for b in cars], dtype=float).reshape(-1, 4)  # w, x, y, z
        vel = np.array([b.get("velocity", [0.0, 0.0])[:2] for b in cars], dtype=float).reshape(-1, 2)
        score = np.array([b["detection_score"] for b in cars], dtype=float) if with_score else np.full(len(cars), np.nan)
    except (KeyError, ValueError, TypeError) as exc:
        raise ScenarioError(f"{path}: sample '{token}': field {exc} of a box is missing or malformed") from exc
    yaw = np.arctan2(2.0 * (q[:, 0] * q[:, 3] + q[:, 1] * q[:, 2]), 1.0 - 2.0 * (q[:, 2] ** 2 + q[:, 3] ** 2))
    return {
        "ids": np.arange(len(cars)), "x": xyz[:, 0], "y": xyz[:, 1], "yaw": yaw, "vx": np.nan_to_num(vel[:, 0]),
        "vy": np.nan_to_num(vel[:, 1]), "length": wlh[:, 1], "width": wlh[:, 0], "height": wlh[:, 2], "score": score,
    }


def load_pairs(ground_truth: Path, results: Path) -> tuple[BoxSequence, BoxSequence, np.ndarray]:
    """(truth, predictions, ego_xy) over the samples that have ground-truth cars."""
    gt, pred = _read(ground_truth), _read(results)
    tokens = [t for t, boxes in gt.items() if any(b.get("detection_name") == CLASS for b in boxes)]
    if not tokens:
        raise ScenarioError(f"{ground_truth}: field 'results' holds no ground-truth box of class car")
    ego = []
    for token in tokens:
        box = next(b for b in gt[token] if b.get("detection_name") == CLASS)
        if "ego_translation" not in box:
            raise ScenarioError(f"{ground_truth}: sample '{token}': field 'ego_translation' is missing")
        ego.append(np.asarray(box["translation"][:2], float) - np.asarray(box["ego_translation"][:2], float))
    truth = BoxSequence.stack([_frame(gt[t], ground_truth, t, with_score=False) for t in tokens])
    predicted = BoxSequence.stack([_frame(pred.get(t, []), results, t, with_score=True) for t in tokens])
    return truth, predicted, np.array(ego)
