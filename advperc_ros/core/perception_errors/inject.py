"""The attack function I(y, e): the detections a perception error tensor makes of the truth.

Each kind adds its piece (`ErrorKind.source`, `show`, `slots`), in the registry's order; the
detections keep their cells' confidences.
"""

from dataclasses import fields
from functools import lru_cache

import numpy as np

import advperc_ros.core.perception_errors.registry as registry
from advperc_ros.core.boxes import BOX_FIELDS, BoxSequence
from advperc_ros.core.geometry import wrap_angle
from advperc_ros.core.perception_errors.kind import Shown
from advperc_ros.core.perception_errors.tensor import PerceptionErrors

CONFIDENCE_SEED = 20240617


@lru_cache(maxsize=64)
def confidence_scores(num_frames: int, num_agents: int) -> np.ndarray:
    """Confidence of the detection of agent j at frame k: strictly distinct, in (0, 1).

    A fixed pseudo-random permutation of the object-frames, independent of the errors, so an attack
    can neither exploit ties (the devkit would take ATE and AOE from a single box) nor choose which
    of its errors the precision-recall curve sees first. A late, resized, flipped or wrongly fast
    detection keeps its cell's confidence: these are errors of a detection, not new detections.
    """
    count = num_frames * num_agents
    rank = np.random.default_rng(CONFIDENCE_SEED).permutation(count)
    scores = ((rank + 1.0) / (count + 1.0)).reshape(num_frames, num_agents)
    scores.setflags(write=False)
    return scores


def _perceive(truth: BoxSequence, errors: PerceptionErrors, rows: slice) -> BoxSequence:
    """I(y, e) on the frames `rows` of `truth`: agent slots first, then any slots a kind adds. The
    one definition both `inject` and `inject_frame` use; it reads truth only up to its rows' frames.
    First the truth frames the detections show (a kind's `source`: a latency's), then each kind's
    change to them, then the heading turned and wrapped once."""
    kinds = [kind for kind in registry.KINDS if kind.present(errors)]
    agents = np.arange(truth.shape[1])
    frames = next((kind.source(truth.valid, errors, rows) for kind in kinds if kind.source is not None), None)
    if frames is None:
        source = {name: getattr(truth, name)[rows] for name in BOX_FIELDS[:-1]}
    else:
        source = {name: getattr(truth, name)[frames, agents] for name in BOX_FIELDS[:-1]}
    shown = Shown(source=source, boxes=dict(source), valid=truth.valid[rows])
    for kind in kinds:
        if kind.show is not None:
            kind.show(shown, errors, rows)
    if shown.turn is not None:
        shown.boxes["yaw"] = wrap_angle(source["yaw"] + shown.turn)
    shown.boxes["score"] = confidence_scores(*truth.shape)[rows]
    out = BoxSequence(ids=truth.ids[rows], valid=shown.valid, **shown.boxes)
    for kind in kinds:
        if kind.slots is not None:
            added = kind.slots(errors, rows)
            out = BoxSequence(**{f.name: np.hstack([getattr(out, f.name), added[f.name]]) for f in fields(out)})
    return out


def inject(truth: BoxSequence, errors: PerceptionErrors) -> BoxSequence:
    """I(y, e) over whole sequences: agent slots as in `truth` (the dropped ones invalid), then one
    slot per ghost."""
    if errors.shape != truth.shape:
        raise ValueError(f"error tensor shape {errors.shape} does not match ground truth {truth.shape}")
    return _perceive(truth, errors, slice(None))


def inject_frame(history: BoxSequence, frame: int, errors: PerceptionErrors) -> dict[str, np.ndarray]:
    """I(y, e) for one frame, as the graph's injector node applies it: `history` the ground truth
    of the rollout's frames so far in the error tensor's slots (frames to come may be left invalid),
    `frame` the one to perceive. The boxes are `inject`'s for that frame, float for float and in the
    same order."""
    return _perceive(history, errors, slice(frame, frame + 1)).frame(0)
