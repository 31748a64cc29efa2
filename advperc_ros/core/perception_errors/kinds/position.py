"""The paper's position error: a world-frame offset of the detected box's centre.

Its wrongness is the offset over the loosest match threshold (beyond it no threshold credits the
detection, as wrong as a drop); its moves are the search method's own (the paper's proposals, the
guided search's pushes), so the record has none.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from advperc_ros.core.metrics.nds import DIST_THRESHOLDS
from advperc_ros.core.perception_errors.kind import ArraySpec, ErrorKind, MatchedBoxes, Shown

if TYPE_CHECKING:
    from advperc_ros.core.perception_errors.tensor import ErrorSpace, PerceptionErrors


def _show(shown: Shown, errors: PerceptionErrors, rows: slice) -> None:
    shown.boxes["x"] = shown.source["x"] + errors.dx[rows]
    shown.boxes["y"] = shown.source["y"] + errors.dy[rows]


def _wrongness(errors: PerceptionErrors, space: ErrorSpace) -> np.ndarray:
    return np.minimum(np.hypot(errors.dx, errors.dy) / max(DIST_THRESHOLDS), 1.0)


def _read_back(matches: MatchedBoxes) -> dict[str, np.ndarray]:
    return {"dx": matches.at_matches(matches.difference("x")), "dy": matches.at_matches(matches.difference("y"))}


KIND = ErrorKind(
    name="position", arrays=(ArraySpec("dx", 0.0), ArraySpec("dy", 0.0)), paper=True,
    show=_show, wrongness=_wrongness, read_back=_read_back,
)
