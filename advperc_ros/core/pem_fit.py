"""Fitting a perception error model to a detector's output: the training set `advperc pem fit`
builds from pairs of ground truth and perceived objects (bags, or nuScenes results), and the fit.

Kept apart from `core.pem` (the model itself) because assembling the set needs the metrics'
matching (`core.metrics.scores`), which imports the model.
"""

from collections.abc import Iterable, Sequence

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.metrics.scores import matched_errors
from advperc_ros.core.pem import PEM, bearings, features, fit
from advperc_ros.exceptions import BagError

MIN_OBJECT_FRAMES = 50  # counted object-frames a fit needs at least,
MIN_DETECTED = 20  # and detected ones among them


def training_set(pairs: Iterable[tuple[BoxSequence, BoxSequence, np.ndarray]]
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(features, detected, radial/tangential position error, yaw error) of every counted
    object-frame of (truth, perceived, ego_xy) pairs: the errors of the matches the metrics make."""
    phis, detected, rts, yaws = [], [], [], []
    for truth, perceived, ego_xy in pairs:
        errors, counted, _ = matched_errors(truth, perceived, ego_xy)
        bearing = bearings(truth, ego_xy)
        c, s = np.cos(bearing), np.sin(bearing)
        rt = np.stack([c * errors.dx + s * errors.dy, -s * errors.dx + c * errors.dy], axis=-1)
        phis.append(features(truth, ego_xy)[counted])
        detected.append(~errors.fn[counted])
        rts.append(rt[counted])
        yaws.append(errors.dyaw[counted])
    return np.concatenate(phis), np.concatenate(detected), np.concatenate(rts), np.concatenate(yaws)


def fit_pem(pairs: Iterable[tuple[BoxSequence, BoxSequence, np.ndarray]], inputs: Sequence[str]) -> tuple[PEM, str]:
    """The model fitted to the pairs read from `inputs`, and its provenance line; one BagError line
    when they hold too few object-frames to fit."""
    phi, detected, rt, dyaw = training_set(pairs)
    if detected.size < MIN_OBJECT_FRAMES or detected.sum() < MIN_DETECTED:
        raise BagError(f"{inputs[0]}: too few object-frames to fit ({detected.size}, {detected.sum()} detected)")
    source = f"fitted by advperc pem fit on {', '.join(inputs)} ({detected.size} object-frames)"
    return fit(phi, detected, rt, dyaw, source), source
