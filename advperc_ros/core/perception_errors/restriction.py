"""One error kind, at one range of distances from the ego, bounded by one magnitude: the error space of a
perception requirement ("misses of up to 0.6 s within 20 m").

A search restricted this way searches as it always does; every error tensor it proposes is projected
onto the restriction before it is scored or rolled out (`Restriction.project`), so what it finds, and
what its results folder saves, lies inside it by construction: every other kind's arrays at their
neutral values, the kind's errors only on the object-frames in the distance bin (the centre of the car
within [near, far) of the ego's centre, as the ground-truth rollout drove), and each error no larger
than the magnitude:

- drop: a car's detections are missed for at most the magnitude (s) in all while it is in the bin, however
  the misses are spread (its first missed frames are kept): a bound on each run alone would let a search
  hide a car again and again with a frame of it between, which a tracker that deletes tracks quickly
  turns into a car that is never there;
- position: the offset's length at most the magnitude (m), its direction kept;
- yaw: the heading error at most the magnitude (rad);
- velocity: the velocity error's length at most the magnitude (m/s), its direction kept;
- size: the length and width factors within 1 / (1 + m) and 1 + m (m: the relative size error);
- latency: a detection lags its car by at most the magnitude (s), whole frames;
- ghost: phantom cars (detections no car explains) are shown for at most the magnitude (s) in all, counting
  every ghost slot's frames, and only where the phantom stands within [near, far) of the ego: a false-positive
  rate, as ghosts per second, is this over the scenario's duration. Its first ghost-frames are kept, frame by
  frame and then slot by slot, as a drop keeps a car's first misses.

A missed detection is not one of the other kinds' errors, yet the search's first phase (the paper's
heuristic) asks which cars matter by hiding each; so under another kind's requirement a missed
object-frame is shown as that kind's nearest thing to not being there, at the full magnitude: moved
sideways away from the ego (position), shown pulling away from it (velocity), shrunk (size), or lagging
(latency). A yaw error and a ghost have no such counterpart: the miss is simply shown.
"""

import math
from dataclasses import dataclass

import numpy as np

from advperc_ros.core.perception_errors.tensor import PerceptionErrors


@dataclass(frozen=True)
class KindMagnitude:
    """How large an error of one kind is, in what unit, and the largest magnitude a requirement asks about
    (the top of its bisection) by default."""

    unit: str
    largest: float
    description: str


MAGNITUDES = {
    "drop": KindMagnitude("s", 10.0, "time a car's detections are missed in all"),  # the paper's drops last seconds
    "position": KindMagnitude("m", 4.0, "largest position error"),
    "yaw": KindMagnitude("rad", 1.0, "largest heading error"),
    "velocity": KindMagnitude("m/s", 8.0, "largest velocity error"),
    "size": KindMagnitude("relative", 1.0, "largest relative length and width error"),
    "latency": KindMagnitude("s", 1.0, "longest lag of a detection behind its car"),
    "ghost": KindMagnitude("s", 10.0, "time phantom cars are shown in all"),  # as drop: a miss's mirror image
}
"""The kinds a requirement bounds, by name: each with the unit of its magnitude."""
DEFAULT_KINDS = ("drop", "position")  # what `advperc requirements` bounds unless told: the paper's two that attack
DEFAULT_RADII = (20.0, 40.0, 60.0)  # m, the distance bins' outer radii, as scenario_simulator_v2's `ellipse_y_radii`
DEFAULT_ITERATIONS = 5  # halvings of a bracket after the largest magnitude broke: 1/32 of it wide


def distance_mask(agents_x: np.ndarray, agents_y: np.ndarray, valid: np.ndarray, ego_xy: np.ndarray, near: float,
                  far: float) -> np.ndarray:
    """(frames x agents) whether each object-frame's centre lies within [near, far) of the ego's centre at that
    frame (`ego_xy` (K, 2), K frames of a rollout; the frames past it count as at its last position)."""
    frames = agents_x.shape[0]
    ego = ego_xy[np.minimum(np.arange(frames), len(ego_xy) - 1)]
    distance = np.hypot(agents_x - ego[:, :1], agents_y - ego[:, 1:2])
    return valid & (distance >= near) & (distance < far)


def _shortened(dx: np.ndarray, dy: np.ndarray, within: np.ndarray, longest: float) -> tuple[np.ndarray, np.ndarray]:
    """(dx, dy) zero outside `within` and no longer than `longest`, the direction kept; a vector within a part in
    10^12 of it is left as it is, so that a tensor projected once is projected again onto itself."""
    length = np.hypot(dx, dy)
    scale = np.where(length > longest * (1.0 + 1e-12), longest / np.maximum(length, 1e-300), 1.0)
    scale = np.where(within, scale, 0.0)
    return dx * scale, dy * scale


def _first_missed(hidden: np.ndarray, frames: int) -> np.ndarray:
    """`hidden` (frames x agents) with each agent's missed frames after its first `frames` of them shown."""
    return hidden & (np.cumsum(hidden, axis=0) <= frames)


@dataclass(frozen=True)
class Scene:
    """What a projection reads besides the errors: the object-frames in the distance bin, the true boxes'
    positions and headings, the ego's centre per frame, and the frame period."""

    within: np.ndarray  # (frames x agents) bool
    x: np.ndarray  # (frames x agents) m
    y: np.ndarray
    yaw: np.ndarray  # rad
    ego_xy: np.ndarray  # (frames, 2) m
    dt: float  # s

    @classmethod
    def of(cls, x: np.ndarray, y: np.ndarray, yaw: np.ndarray, valid: np.ndarray, ego_xy: np.ndarray, dt: float,
           near: float, far: float) -> "Scene":
        """The scene of a rollout whose ego drove `ego_xy` (K frames; past them, at its last position)."""
        ego = ego_xy[np.minimum(np.arange(x.shape[0]), len(ego_xy) - 1)]
        return cls(distance_mask(x, y, valid, ego_xy, near, far), x, y, yaw, ego, dt)

    def away(self) -> tuple[np.ndarray, np.ndarray]:
        """(cx, cy) per object-frame: the unit normal of the car's heading on the side away from the ego."""
        nx, ny = -np.sin(self.yaw), np.cos(self.yaw)
        towards_ego = nx * (self.ego_xy[:, :1] - self.x) + ny * (self.ego_xy[:, 1:2] - self.y)
        side = np.where(towards_ego >= 0.0, -1.0, 1.0)
        return side * nx, side * ny

    def ahead(self) -> tuple[np.ndarray, np.ndarray]:
        """(cx, cy) per object-frame: the unit vector along the car's heading or against it, whichever points
        away from the ego (a car shown moving that way seems to pull away)."""
        cx, cy = np.cos(self.yaw), np.sin(self.yaw)
        side = np.where(cx * (self.x - self.ego_xy[:, :1]) + cy * (self.y - self.ego_xy[:, 1:2]) >= 0.0, 1.0, -1.0)
        return side * cx, side * cy


@dataclass(frozen=True)
class Restriction:
    """The error space of one requirement: `kind`'s errors only, on object-frames within [near, far) m of
    the ego, at most `magnitude` (in the kind's unit, `MAGNITUDES`)."""

    kind: str
    magnitude: float
    near: float = 0.0
    far: float = math.inf

    def __post_init__(self) -> None:
        if self.kind not in MAGNITUDES:
            raise ValueError(f"a requirement bounds one of {', '.join(MAGNITUDES)}, not {self.kind!r}")
        if not (self.magnitude >= 0.0 and math.isfinite(self.magnitude)):
            raise ValueError(f"a requirement's magnitude must be a finite number >= 0, got {self.magnitude!r}")
        if not 0.0 <= self.near < self.far:
            raise ValueError(f"a distance bin must have 0 <= near < far, got [{self.near!r}, {self.far!r})")

    def project(self, errors: PerceptionErrors, scene: Scene) -> PerceptionErrors:
        """`errors` inside the restriction, in `scene` (its distance bin, its cars and ego)."""
        frames, agents = errors.shape
        out = PerceptionErrors.none(frames, agents, errors.kinds, errors.ghost_slots)
        kept, given, within, m = out.arrays(), errors.arrays(), scene.within, self.magnitude
        missed = given["fn"] & within  # shown instead as the kind's own worst (module docstring)
        whole_frames = int(math.floor(m / scene.dt + 1e-9))
        if self.kind == "drop":
            kept["fn"][:] = _first_missed(missed, whole_frames)
        elif self.kind in ("position", "velocity"):
            a, b = ("dx", "dy") if self.kind == "position" else ("dvx", "dvy")
            cx, cy = scene.away() if self.kind == "position" else scene.ahead()
            dx, dy = _shortened(given[a], given[b], within, m)
            kept[a][:], kept[b][:] = np.where(missed, m * cx, dx), np.where(missed, m * cy, dy)
        elif self.kind == "yaw":
            kept["dyaw"][:] = np.where(within, np.clip(given["dyaw"], -m, m), 0.0)
        elif self.kind == "size":
            for name in ("length_scale", "width_scale"):
                kept[name][:] = np.where(missed, 1.0 / (1.0 + m),
                                         np.where(within, np.clip(given[name], 1.0 / (1.0 + m), 1.0 + m), 1.0))
        elif self.kind == "latency":
            kept["latency"][:] = np.where(missed, whole_frames,
                                          np.where(within, np.minimum(given["latency"], whole_frames), 0))
        else:  # ghost
            self._keep_ghosts(given, kept, scene, whole_frames)
        return out

    def _keep_ghosts(self, given: dict[str, np.ndarray], kept: dict[str, np.ndarray], scene: Scene,
                     whole_frames: int) -> None:
        """Into `kept`: the ghost-frames of `given` in the distance bin (each phantom's own distance from the
        ego), the first `whole_frames` of them in all (frame by frame, slot by slot), each with its box."""
        on = given.get("ghost_on")
        if on is None or on.size == 0:
            return
        distance = np.hypot(given["ghost_x"] - scene.ego_xy[:, :1], given["ghost_y"] - scene.ego_xy[:, 1:2])
        shown = on & (distance >= self.near) & (distance < self.far)
        shown &= (np.cumsum(shown.ravel()) <= whole_frames).reshape(shown.shape)
        kept["ghost_on"][:] = shown
        for name in ("ghost_x", "ghost_y", "ghost_yaw", "ghost_vx", "ghost_vy"):
            kept[name][:] = np.where(shown, given[name], kept[name])
