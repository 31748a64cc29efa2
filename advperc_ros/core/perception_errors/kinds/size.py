"""A size error: the detection's length and width each a factor of the truth's.

Its move shows a run of a car larger or smaller than it is (a planner's clearance). Bounded by
`min_scale` and `max_scale`, its wrongness is |log(length scale x width scale)| over the widest
log ratio the bounds allow.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from advperc_ros.core.perception_errors.kind import ArraySpec, Bound, ErrorKind, MatchedBoxes, MoveContext, Shown
from advperc_ros.core.perception_errors.moves import car_move

if TYPE_CHECKING:
    from advperc_ros.core.perception_errors.tensor import ErrorSpace, PerceptionErrors


def _show(shown: Shown, errors: PerceptionErrors, rows: slice) -> None:
    assert errors.length_scale is not None and errors.width_scale is not None
    shown.boxes["length"] = shown.source["length"] * errors.length_scale[rows]
    shown.boxes["width"] = shown.source["width"] * errors.width_scale[rows]


def _wrongness(errors: PerceptionErrors, space: ErrorSpace) -> np.ndarray:
    assert errors.length_scale is not None and errors.width_scale is not None
    widest = np.log(space.max_scale / space.min_scale)
    return np.minimum(np.abs(np.log(errors.length_scale * errors.width_scale)) / widest, 1.0)


def _read_back(matches: MatchedBoxes) -> dict[str, np.ndarray]:
    f, p, g = matches.frame, matches.prediction, matches.agent
    perceived, truth = matches.perceived, matches.truth
    with np.errstate(divide="ignore", invalid="ignore"):  # a zero-sized truth (nuScenes JSON may hold one)
        return {"length_scale": matches.at_matches(perceived.length[f, p] / truth.length[f, g], 1.0),
                "width_scale": matches.at_matches(perceived.width[f, p] / truth.width[f, g], 1.0)}


def _wrong_size(out: PerceptionErrors, j: int, rows: slice, rng: np.random.Generator, context: MoveContext) -> None:
    """A run of a car shown with its length and width each scaled by a factor uniform in the bounds."""
    assert out.length_scale is not None and out.width_scale is not None
    out.length_scale[rows, j], out.width_scale[rows, j] = rng.uniform(context.space.min_scale, context.space.max_scale,
                                                                      size=2)


resized = car_move("size", _wrong_size)

KIND = ErrorKind(
    name="size", arrays=(ArraySpec("length_scale", 1.0, above=0.0), ArraySpec("width_scale", 1.0, above=0.0)),
    bounds=(Bound("min_scale", 0.5, "size kind: the smallest factor on a detection's length and width", positive=True,
                  high=1.0),
            Bound("max_scale", 2.0, "size kind: the largest factor on a detection's length and width", low=1.0,
                  high=10.0)),
    show=_show, wrongness=_wrongness, read_back=_read_back,
    moves=(("resized", resized),),
)
