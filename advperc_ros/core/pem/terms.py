"""The model's terms beyond the paper's parts, one per error kind that has one, in the kinds'
registry order (`core.perception_errors.KINDS`): the fields each adds to the model, what switches it
on, its per-object-frame log density where it adds one, and its draw of its kind's arrays.

A term is off at its fields' neutral values, so a model without it scores and samples exactly as the
paper's parts alone. The model loops over `TERMS` to score, to sample and to check its fields; the
flip term's density is the yaw part's mixture and the false-positive term's the frames' Poisson,
which the model computes in those parts.
"""

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from advperc_ros.core.boxes import CLASS_RANGE, BoxSequence, in_range
from advperc_ros.core.pem.densities import _normal_logpdf, _student_t_2d_logpdf, to_world
from advperc_ros.core.pem.field import Field
from advperc_ros.core.pem.frames import ObjectFrames
from advperc_ros.core.perception_errors import ErrorSpace

if TYPE_CHECKING:
    from advperc_ros.core.pem.model import PEM

MAX_LATENCY = 100  # frames a model's latency may be (a bound that keeps latency_source's loop short)
GHOST_SLOTS = ErrorSpace().ghosts  # sampled ghosts per frame at most (the attack's own bound)


@dataclass(frozen=True)
class Draw:
    """What a term's draw reads: the truth, the ego's positions, the model's features of the truth and
    each box's bearing from the ego."""

    truth: BoxSequence
    ego_xy: np.ndarray
    phi: np.ndarray
    bearing: np.ndarray


@dataclass(frozen=True)
class Term:
    """One term of the model, for the error kind `kind` (module docstring): its `fields` and what each
    may hold; `together`, fields that are above 0 exactly when the first is (a term on or off as a
    whole); `on`, whether a model has it; `log_density(model, frames, velocity)`, its share of each
    object-frame's log-likelihood (`velocity`: the errors from the truth the latency shows); `sample`,
    its kind's arrays drawn for a `Draw`."""

    kind: str
    fields: dict[str, Field]
    on: Callable[["PEM"], bool]
    sample: Callable[["PEM", Draw, np.random.Generator], dict[str, np.ndarray]]
    together: tuple[str, ...] = ()
    log_density: Callable[["PEM", ObjectFrames, np.ndarray], np.ndarray] | None = None


def _velocity_density(model: "PEM", frames: ObjectFrames, velocity: np.ndarray) -> np.ndarray:
    """Radial/tangential bivariate Student-t with constant scales."""
    return _student_t_2d_logpdf(velocity, np.zeros(2), model.velocity_radial_scale, model.velocity_tangential_scale,
                                0.0, model.velocity_nu)


def _velocity_sample(model: "PEM", draw: Draw, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """The bivariate t: a normal pair over one sqrt(chi2 / nu), turned to the world frame."""
    shape = draw.truth.shape
    g = rng.standard_normal((*shape, 2))
    w = np.sqrt(rng.chisquare(model.velocity_nu, shape) / model.velocity_nu)[..., None]
    scales = np.array([model.velocity_radial_scale, model.velocity_tangential_scale])
    dvx, dvy = to_world(scales * g / w, draw.bearing)
    return {"dvx": dvx, "dvy": dvy}


def _size_density(model: "PEM", frames: ObjectFrames, velocity: np.ndarray) -> np.ndarray:
    """log(length scale) and log(width scale) independent normals."""
    return (_normal_logpdf(frames.log_size[:, 0], model.length_log_loc, model.length_log_std)
            + _normal_logpdf(frames.log_size[:, 1], model.width_log_loc, model.width_log_std))


def _size_sample(model: "PEM", draw: Draw, rng: np.random.Generator) -> dict[str, np.ndarray]:
    shape = draw.truth.shape
    length = np.exp(rng.normal(model.length_log_loc, model.length_log_std, shape))
    return {"length_scale": length, "width_scale": np.exp(rng.normal(model.width_log_loc, model.width_log_std, shape))}


def _flip_sample(model: "PEM", draw: Draw, rng: np.random.Generator) -> dict[str, np.ndarray]:
    return {"flip": rng.random(draw.truth.shape) < model.flip_probability(draw.phi)}


def _latency_sample(model: "PEM", draw: Draw, rng: np.random.Generator) -> dict[str, np.ndarray]:
    return {"latency": np.full(draw.truth.shape, model.frames_late, dtype=np.int64)}


def _ghost_sample(model: "PEM", draw: Draw, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Ghost detections: per frame a Poisson number with the scored mean (at most GHOST_SLOTS, the
    attack's bound), each uniform over the disc in range around the ego, its heading uniform, moving
    along it at the speed of a random present agent-frame: as the cars of this scene move."""
    truth, ego_xy = draw.truth, draw.ego_xy
    frames = truth.shape[0]
    mean = model.false_positive_rate * np.count_nonzero(in_range(truth, ego_xy)) / frames
    count = np.minimum(rng.poisson(mean, frames), GHOST_SLOTS)
    shape = (frames, GHOST_SLOTS)
    radius = CLASS_RANGE * np.sqrt(rng.random(shape))
    bearing = rng.uniform(-np.pi, np.pi, shape)
    yaw = rng.uniform(-np.pi, np.pi, shape)
    speeds = np.hypot(truth.vx, truth.vy)[truth.valid]
    speed = rng.choice(speeds, shape) if speeds.size else np.zeros(shape)
    return {
        "ghost_on": np.arange(GHOST_SLOTS) < count[:, None],
        "ghost_x": ego_xy[:, :1] + radius * np.cos(bearing), "ghost_y": ego_xy[:, 1:2] + radius * np.sin(bearing),
        "ghost_yaw": yaw, "ghost_vx": speed * np.cos(yaw), "ghost_vy": speed * np.sin(yaw),
    }


TERMS: tuple[Term, ...] = (
    Term("velocity", {"velocity_radial_scale": Field(None, 0.0, closed=True),
                      "velocity_tangential_scale": Field(None, 0.0, closed=True),
                      "velocity_nu": Field(None, 0.0, closed=True)},
         on=lambda model: model.models_velocity, sample=_velocity_sample, log_density=_velocity_density,
         together=("velocity_radial_scale", "velocity_tangential_scale", "velocity_nu")),
    Term("size", {"length_log_loc": Field(None), "length_log_std": Field(None, 0.0, closed=True),
                  "width_log_loc": Field(None), "width_log_std": Field(None, 0.0, closed=True)},
         on=lambda model: model.models_size, sample=_size_sample, log_density=_size_density,
         together=("length_log_std", "width_log_std")),
    Term("flip", {"flip_near": Field(None, 0.0, 1.0, closed=True), "flip_far": Field(None, 0.0, 1.0, closed=True)},
         on=lambda model: model.models_flips, sample=_flip_sample),
    Term("latency", {"latency": Field(None, 0.0, MAX_LATENCY + 1.0, closed=True, whole=True)},
         on=lambda model: model.frames_late > 0, sample=_latency_sample),
    Term("ghost", {"false_positive_rate": Field(None, 0.0, 1000.0, closed=True)},  # beyond, no detector (nor Poisson)
         on=lambda model: model.false_positive_rate > 0.0, sample=_ghost_sample),
)
