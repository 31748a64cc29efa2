"""A heading flip: the detection heading the other way (its yaw turned by pi).

Its move shows a run of a car turned around (a prediction that points away). A turned car counts
as wrong as it can be (wrongness 1): its heading is. The metrics do not read it back apart: a
flipped match is a yaw error of about pi, which the perception error model's flip term scores.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from advperc_ros.core.perception_errors.kind import ArraySpec, ErrorKind, MoveContext, Shown
from advperc_ros.core.perception_errors.moves import car_move

if TYPE_CHECKING:
    from advperc_ros.core.perception_errors.tensor import ErrorSpace, PerceptionErrors


def _show(shown: Shown, errors: PerceptionErrors, rows: slice) -> None:
    assert errors.flip is not None
    half_turns = np.pi * errors.flip[rows]
    shown.turn = half_turns if shown.turn is None else shown.turn + half_turns


def _wrongness(errors: PerceptionErrors, space: ErrorSpace) -> np.ndarray:
    assert errors.flip is not None
    return errors.flip.astype(float)


def _heading_flipped(out: PerceptionErrors, j: int, rows: slice, rng: np.random.Generator, context: MoveContext) -> None:
    """A run of a car shown heading the other way."""
    assert out.flip is not None
    out.flip[rows, j] = True


turned_around = car_move("flip", _heading_flipped)

KIND = ErrorKind(
    name="flip", arrays=(ArraySpec("flip", False, np.bool_),), show=_show, wrongness=_wrongness,
    moves=(("turned_around", turned_around),),
)
