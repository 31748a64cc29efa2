"""Fitting a perception error model to a detector's output: the training set `advperc pem fit`
builds from pairs of ground truth and perceived objects (bags, or nuScenes results), and the fit.

Kept apart from `core.pem` (the model itself) because assembling the set needs the metrics'
matching (`core.metrics.scores`), which imports the model.
"""

from collections.abc import Iterable, Sequence

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.metrics.scores import matched_errors
from advperc_ros.core.pem import FIT_LATENCIES, PEM, ObjectFrames, features, fit_object_frames, object_frames
from advperc_ros.exceptions import BagError

MIN_OBJECT_FRAMES = 50  # counted object-frames a fit needs at least,
MIN_DETECTED = 20  # and detected ones among them,
MIN_FOLLOWING = 20  # and, with track identity, detections that follow an earlier one of their agent
COPIED = 1e-6  # m: a detection this near its truth in both position components is the truth copied, not detected
MAX_COPIED_SHARE = 0.5  # detections of an input that may be copies: a detector's are never exact, an attack's mostly


def training_set(pairs: Iterable[tuple[BoxSequence, BoxSequence, np.ndarray]], tracked: bool = True) -> ObjectFrames:
    """The counted object-frames of (truth, perceived, ego_xy) pairs, with the errors of the matches
    the metrics make and the frames' false positives; with `tracked` (a truth slot is one agent in
    every frame, as in bags) also the lags of every latency a fit tries."""
    latencies = tuple(range(1, FIT_LATENCIES + 1)) if tracked else ()
    parts = []
    for truth, perceived, ego_xy in pairs:
        errors, counted, _ = matched_errors(truth, perceived, ego_xy)
        parts.append(object_frames(truth, errors, ego_xy, counted, features(truth, ego_xy), latencies, tracked))
    return ObjectFrames.concatenate(parts)


def fit_pem(pairs: Iterable[tuple[BoxSequence, BoxSequence, np.ndarray]], inputs: Sequence[str],
            tracked: bool = True) -> tuple[PEM, str]:
    """The model fitted to the pairs read from `inputs`, and its provenance line; one BagError line
    when they hold too few object-frames to fit (or, `tracked`, too few detections following one of
    their agent's to fit how errors persist). Without track identity (nuScenes results: a sample's
    slots are its boxes) latency and persistence are not fitted, and the provenance says so."""
    frames = training_set(pairs, tracked)
    detected = frames.detected
    if detected.size < MIN_OBJECT_FRAMES or detected.sum() < MIN_DETECTED:
        raise BagError(f"{inputs[0]}: too few object-frames to fit ({detected.size}, {detected.sum()} detected)")
    following = int(np.count_nonzero(frames.previous[detected] >= 0))
    if tracked and following < MIN_FOLLOWING:
        raise BagError(f"{inputs[0]}: too few detections follow an earlier one of their agent to fit how position "
                       f"errors persist ({following}, {MIN_FOLLOWING} needed)")
    _refuse_copied_truth(", ".join(inputs), frames)
    source = f"fitted by advperc pem fit on {', '.join(inputs)} ({detected.size} object-frames)"
    if not tracked:
        source += "; no track identity, so no latency or persistence fitted"
    return fit_object_frames(frames, source, tracked), source


def _refuse_copied_truth(name: str, frames: ObjectFrames) -> None:
    """One BagError line when most detections of the inputs `name` are their ground truth to the micrometre: an
    attack bag's (the truth with the attack's errors) or the truth itself on the detections topic. A model fitted
    to them says a detector makes no errors (scales at their floor), which would score any attack as typical."""
    position = frames.position[frames.detected]
    copied = int(np.count_nonzero(np.all(np.abs(position) < COPIED, axis=1)))
    if position.size and copied > MAX_COPIED_SHARE * len(position):
        raise BagError(f"{name}: {copied} of {len(position)} detections are their ground truth to the micrometre: "
                       "no detector's output (an attack bag's, or the truth on the detections topic); fit a log of "
                       "your detector")
