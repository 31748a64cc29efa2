"""The paper's false negative: the detection of an agent on a frame is dropped.

A drop is as wrong as an object-frame can be (wrongness 1); it counts as used wherever it is, as a
dropped detection shows no other error.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from advperc_ros.core.perception_errors.kind import ArraySpec, ErrorKind, MatchedBoxes, Shown

if TYPE_CHECKING:
    from advperc_ros.core.perception_errors.tensor import ErrorSpace, PerceptionErrors


def _show(shown: Shown, errors: PerceptionErrors, rows: slice) -> None:
    shown.valid = shown.valid & ~errors.fn[rows]


def _wrongness(errors: PerceptionErrors, space: ErrorSpace) -> np.ndarray:
    return errors.fn.astype(float)


def _read_back(matches: MatchedBoxes) -> dict[str, np.ndarray]:
    """Dropped where no detection matched the truth slot."""
    fn = np.ones(matches.truth.shape, dtype=bool)
    fn[matches.frame, matches.agent] = False
    return {"fn": fn}


def _used(errors: PerceptionErrors, rows: slice) -> bool:
    return bool(errors.fn[rows].any())


KIND = ErrorKind(name="drop", arrays=(ArraySpec("fn", False, np.bool_),), paper=True, show=_show,
                 wrongness=_wrongness, read_back=_read_back, used=_used)
