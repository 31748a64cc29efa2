"""The paper's yaw error: an offset of the detected heading.

A yaw error alone is noise (the paper's proposals add it to every displaced frame), so an
object-frame turned only by it is not attacked and not wrong to the guided search.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from advperc_ros.core.geometry import wrap_angle
from advperc_ros.core.perception_errors.kind import ArraySpec, ErrorKind, MatchedBoxes, Shown

if TYPE_CHECKING:
    from advperc_ros.core.perception_errors.tensor import PerceptionErrors


def _show(shown: Shown, errors: PerceptionErrors, rows: slice) -> None:
    shown.turn = errors.dyaw[rows]


def _read_back(matches: MatchedBoxes) -> dict[str, np.ndarray]:
    return {"dyaw": matches.at_matches(wrap_angle(matches.difference("yaw")))}


KIND = ErrorKind(name="yaw", arrays=(ArraySpec("dyaw", 0.0),), paper=True, attacks=False, show=_show,
                 read_back=_read_back)
