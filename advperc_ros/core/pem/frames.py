"""The object-frames the perception error model scores and a fit learns from, read off a perception
output: one record, so scoring and fitting read one thing."""

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import wrap_angle
from advperc_ros.core.pem.densities import bearings, to_radial
from advperc_ros.core.perception_errors import PerceptionErrors, latency_source

if TYPE_CHECKING:
    from advperc_ros.core.pem.model import PEM

@dataclass(frozen=True)
class ObjectFrames:
    """What the model scores, per counted object-frame (K rows, flat, of one or more sequences), and
    the frames' false positives: read off a perception output by `object_frames`, scored by
    `PEM.log_likelihoods`, fitted by `fit_object_frames`, so scoring and fitting read one thing."""

    phi: np.ndarray  # (K, NUM_FEATURES)
    detected: np.ndarray  # (K,) bool
    position: np.ndarray  # (K, 2) radial/tangential position error from the current truth, m
    dyaw: np.ndarray  # (K,) rad
    velocity: np.ndarray  # (K, 2) radial/tangential velocity error, m/s
    log_size: np.ndarray  # (K, 2) log of the length and width scale
    previous: np.ndarray  # (K,) row of the same agent's previous detected object-frame, -1 if none
    gap: np.ndarray  # (K,) frames back to it
    # latency -> (K, 5): what the agent's own motion over it adds to the errors (position radial and tangential,
    # yaw, velocity radial and tangential)
    lags: dict[int, np.ndarray]
    false_positives: np.ndarray  # (frames,) in-range detections no truth matched
    exposure: np.ndarray  # (frames,) counted object-frames per frame of the frame's sequence

    def lagged(self, latency: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(position, yaw, velocity) errors from the truth a detector `latency` frames late shows."""
        if latency == 0:
            return self.position, self.dyaw, self.velocity
        lag = self.lags[latency]
        return self.position - lag[:, :2], self.dyaw - lag[:, 2], self.velocity - lag[:, 3:]

    @classmethod
    def concatenate(cls, parts: list["ObjectFrames"]) -> "ObjectFrames":
        """One set of the object-frames of several sequences (each row's `previous` stays its own
        sequence's)."""
        offsets = np.cumsum([0] + [len(part.detected) for part in parts[:-1]])
        joined = {f.name: np.concatenate([getattr(part, f.name) for part in parts])
                  for f in fields(cls) if f.name not in ("previous", "lags")}
        previous = np.concatenate([np.where(p.previous >= 0, p.previous + o, -1) for p, o in zip(parts, offsets)])
        lags = {latency: np.concatenate([part.lags[latency] for part in parts]) for latency in parts[0].lags}
        return cls(previous=previous, lags=lags, **joined)


def _previous_detections(observed: np.ndarray, counted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per counted object-frame (in np.nonzero order): the row of the agent's latest earlier observed
    object-frame (-1 if none) and how many frames back it is."""
    frames = np.arange(observed.shape[0])[:, None]
    latest = np.maximum.accumulate(np.where(observed, frames, -1), axis=0)
    before = np.vstack([np.full((1, observed.shape[1]), -1), latest[:-1]])  # latest observed frame before k
    rows = np.full(observed.shape, -1)
    rows[counted] = np.arange(np.count_nonzero(counted))
    previous = np.where(before >= 0, rows[np.maximum(before, 0), np.arange(observed.shape[1])], -1)
    return previous[counted], (frames - before)[counted]


def _lag_offsets(truth: BoxSequence, latency: int, bearing: np.ndarray) -> np.ndarray:
    """(F, M, 5) as `ObjectFrames.lags`: the truth `latency` frames earlier (`latency_source`) minus the present one,
    positions and velocities turned radial/tangential to the present bearing."""
    source = latency_source(truth.valid, np.full(truth.shape, latency), slice(None))
    agents = np.arange(truth.shape[1])

    def back(values: np.ndarray) -> np.ndarray:
        return values[source, agents] - values

    position = to_radial(back(truth.x), back(truth.y), bearing)
    velocity = to_radial(back(truth.vx), back(truth.vy), bearing)
    return np.concatenate([position, wrap_angle(back(truth.yaw))[..., None], velocity], axis=-1)


def object_frames(truth: BoxSequence, errors: PerceptionErrors, ego_xy: np.ndarray, counted: np.ndarray,
                  phi: np.ndarray, latencies: tuple[int, ...] = (), tracked: bool = True,
                  reader: "PEM | None" = None) -> ObjectFrames:
    """The object-frames of one sequence: `errors` as `matched_errors` reads them (its ghost slots the
    in-range detections no truth matched), the lags of `latencies` (besides 0), `tracked` if a slot is
    one agent in every frame (else no agent has a previous detection, and no latency can be told).
    With a `reader`, only what that model scores is read and the rest left neutral (zero errors, no
    previous detection, no false positive): scoring the paper's parts costs what it did before the
    terms beyond them; without, everything is (a fit's)."""
    count = np.count_nonzero(counted)
    bearing = bearings(truth, ego_xy)
    rt = to_radial(errors.dx, errors.dy, bearing)[counted]
    velocity = log_size = np.zeros((count, 2))
    if errors.dvx is not None and errors.dvy is not None and (reader is None or reader.models_velocity):
        velocity = to_radial(errors.dvx, errors.dvy, bearing)[counted]
    if errors.length_scale is not None and errors.width_scale is not None and (reader is None or reader.models_size):
        with np.errstate(divide="ignore"):  # a zero-sized box has no size error to read: -inf, as its density says
            log_size = np.log(np.stack([errors.length_scale[counted], errors.width_scale[counted]], axis=-1))
    previous, gap = np.full(count, -1), np.ones(count, dtype=np.int64)
    if tracked and (reader is None or reader.position_ar != 0.0):
        previous, gap = _previous_detections(counted & ~errors.fn, counted)
    frames = truth.shape[0]
    false_positives = np.zeros(frames)
    if errors.ghost_on is not None and (reader is None or reader.false_positive_rate > 0.0):
        false_positives = errors.ghost_on.sum(axis=1).astype(float)
    return ObjectFrames(
        phi=phi[counted], detected=~errors.fn[counted], position=rt, dyaw=errors.dyaw[counted],
        velocity=velocity, log_size=log_size, previous=previous, gap=gap,
        lags={latency: _lag_offsets(truth, latency, bearing)[counted] for latency in latencies if latency},
        false_positives=false_positives, exposure=np.full(frames, count / frames),
    )
