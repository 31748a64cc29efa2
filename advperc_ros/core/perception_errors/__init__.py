"""The error tensor e, the error kinds it holds and the attack function I(y, e).

The paper's e holds, per frame and agent, a world-frame position offset, a yaw offset and a
false-negative flag; size and velocity stay true. Real detectors fail in more ways, each scored by
nuScenes' metrics, so e may also hold, each only when its kind is enabled (`ERROR_KINDS`): a velocity
error, a length and width scale, a heading flip, a latency (the detection shows the agent as it was
some frames earlier) and, per frame, ghost detections no agent explains. A kind that is off has no
array at all, so a tensor of the paper's kinds is the paper's, to the bit, in memory, on disk and in
every digest.

Each kind is one module of `kinds/` (its `ErrorKind`: arrays, bounds, its piece of the attack
function, wrongness, read-back, moves), ordered by `registry`; the tensor (`tensor`), the attack
function (`inject`), the search, the metrics and the lockstep codec loop over the registry.
"""

from advperc_ros.core.perception_errors.inject import CONFIDENCE_SEED, confidence_scores, inject, inject_frame
from advperc_ros.core.perception_errors.kind import ArraySpec, ErrorKind, MatchedBoxes, Move, MoveContext, Shown
from advperc_ros.core.perception_errors.kinds.ghost import (
    GHOST_CONFIDENCE_QUANTILE,
    GHOST_CONFIDENCE_SEED,
    GHOST_HEIGHT,
    GHOST_LENGTH,
    GHOST_WIDTH,
    ghost_scores,
)
from advperc_ros.core.perception_errors.kinds.latency import latency_source
from advperc_ros.core.perception_errors.registry import (
    ERROR_KINDS,
    EXTENDED_KINDS,
    KINDS,
    PAPER_ARRAYS,
    PAPER_KINDS,
    kind_named,
    parse_error_kinds,
)
from advperc_ros.core.perception_errors.tensor import ErrorSpace, PerceptionErrors

__all__ = [
    "CONFIDENCE_SEED", "ERROR_KINDS", "EXTENDED_KINDS", "GHOST_CONFIDENCE_QUANTILE", "GHOST_CONFIDENCE_SEED",
    "GHOST_HEIGHT", "GHOST_LENGTH", "GHOST_WIDTH", "KINDS", "PAPER_ARRAYS", "PAPER_KINDS", "ArraySpec", "ErrorKind",
    "ErrorSpace", "MatchedBoxes", "Move", "MoveContext", "PerceptionErrors", "Shown", "confidence_scores",
    "ghost_scores", "inject", "inject_frame", "kind_named", "latency_source", "parse_error_kinds",
]
