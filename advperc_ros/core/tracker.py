"""The paper's multi-object tracker: Kalman filter per track, Hungarian association.

State per track: position, orientation as (cos, sin) renormalised every step, and their rates,
under a constant-velocity model. Detections measure position and orientation; a new track takes
its velocity from the detection. Association is on centre distance, gated before and after the
assignment. Tracks are confirmed after one observation, coast while unobserved, and are deleted
after `max_age` seconds without an observation.

The filters of all tracks run as one batch: filterpy's KalmanFilter equations (predict
P = FPF' + Q, update with the Joseph form) on every track at once, which is what makes a rollout
cheap; test_tracker.py checks the numbers against a filterpy filter per track. F, Q and P0 never
correlate x, y, cos and sin with one another (each only with its own rate), and neither does an
update, so P is four 2x2 blocks (a measured component and its rate) and zeros, exactly: the
tracker keeps only the blocks, laid out so that each of their entries is one contiguous array
over components and tracks (few, cheap numpy calls a frame).

Known property kept on purpose: if a car's detections are dropped and it changes speed, the
coasting track drifts away from where the car reappears; the reappearing detection then spawns a
second track while the first coasts on as a phantom until it ages out. Attacks may exploit it.
"""

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from filterpy.common import Q_discrete_white_noise
from scipy.linalg import block_diag
from scipy.optimize import linear_sum_assignment

# The state of track n is state[:, :, n]: row 0 the measured components x, y, c, s ((c, s) =
# (cos yaw, sin yaw)), row 1 their rates vx, vy, vc, vs; its covariance is covariance[:, :, :, n],
# where covariance[i, j, m] is the (i, j) entry of component m's 2x2 block (i, j: 0 the
# component, 1 its rate). filterpy's layout is x, y, vx, vy, c, s, vc, vs: _PAIRS[m] are the
# indices of component m and its rate there.
_PAIRS = np.array([[0, 2], [1, 3], [4, 6], [5, 7]])
_FIRST = np.array([1.0, 0.0])[:, None, None]  # the first column of the 2x2 identity, over (components, tracks)
_UNASSIGNABLE = 1e9
_NONE = np.zeros(0, dtype=np.int64)


@dataclass(frozen=True)
class TrackerConfig:
    """The tracker's association gate, track lifetime and noise. The gate and lifetime are params
    (`tracker.*`, defaults the schema's, a test checks); the noise is fixed, as the paper's."""

    gate: float = 2.0  # m, centre distance, applied before and after assignment
    max_age: float = 1.0  # s without an observation before a track is deleted
    position_std: float = 0.3  # m, measurement noise
    heading_std: float = 0.1  # measurement noise on cos/sin
    accel_std: float = 2.0  # m/s^2, white-acceleration process noise
    heading_accel_std: float = 1.0  # 1/s^2 on cos/sin
    initial_velocity_std: float = 0.5  # m/s, trust in the detection's velocity
    # False when the attacked layer is the tracked objects (param `attacked_layer: tracks`): no tracker
    # between the errors and the planner, which reads the perturbed objects as they are
    in_loop: bool = True


@dataclass(frozen=True)
class Tracks:
    """Every live track, in creation order (association ties follow this order); the last axis
    of every array is the track's.

    The tracker updates state, covariance, last_seen and size in place (never ids), so
    `Tracker.step` hands out copies of those.
    """

    ids: np.ndarray  # (N,) int64
    state: np.ndarray  # (2, 4, N) in the layout above, at the tracker's time
    covariance: np.ndarray  # (2, 2, 4, N)
    last_seen: np.ndarray  # (N,) time of the last observation
    size: np.ndarray  # (3, N) length, width, height of the last observation

    def __len__(self) -> int:
        return len(self.ids)

    def select(self, keep: np.ndarray) -> "Tracks":
        return Tracks(*(np.compress(keep, array, axis=-1) for array in self._arrays()))  # contiguous, as [..., keep] is not

    def copy(self) -> "Tracks":
        """A copy sharing no array the tracker updates in place."""
        return Tracks(*(array.copy() for array in self._arrays()))

    def extend(self, other: "Tracks") -> "Tracks":
        return Tracks(*(np.concatenate([mine, theirs], axis=-1) for mine, theirs in zip(self._arrays(), other._arrays())))

    def _arrays(self) -> tuple[np.ndarray, ...]:
        return self.ids, self.state, self.covariance, self.last_seen, self.size


def _blocks(matrix: np.ndarray) -> np.ndarray:
    """The (2, 2, 4) blocks of an 8x8 matrix in filterpy's layout that never correlates components."""
    return matrix[_PAIRS.T[:, None, :], _PAIRS.T[None, :, :]]


def _associate(cost: np.ndarray, gate: float) -> tuple[np.ndarray, np.ndarray]:
    """(tracks, detections) of the matched pairs, by track: the Hungarian assignment on centre
    distance `cost` (tracks x detections), gated before and after.

    When no track has two detections within the gate and no detection two tracks (the common
    case), every gated pair is in the optimal assignment, as an ungated pair costs more than all
    the gated distances together: they are the answer without solving for it.
    """
    gated = cost <= gate
    rows, cols = np.nonzero(gated)
    if len(set(rows.tolist())) == rows.size and len(set(cols.tolist())) == cols.size:
        return rows, cols
    rows, cols = linear_sum_assignment(np.where(gated, cost, _UNASSIGNABLE))
    ok = gated[rows, cols]
    return rows[ok], cols[ok]


def _renormalise_heading(heading: np.ndarray) -> None:
    """(cos, sin) rows (2, N) back onto the unit circle, in place; a vanishing vector is left alone
    (divided by 1, exactly itself: cheaper than np.divide's where=)."""
    norm = np.hypot(heading[0], heading[1])
    unit = norm > 1e-9
    if np.count_nonzero(unit) < unit.size:
        norm[~unit] = 1.0
    heading /= norm


class ObjectTracker(Protocol):
    """What a rollout needs of the layer between perception and the planner; `snapshot` and `restore`
    let a rollout start mid-scenario from the tracker's memory of an earlier one (core.forks)."""

    def reset(self) -> None: ...

    def step(self, t: float, detections: dict[str, np.ndarray]) -> dict[str, np.ndarray]: ...

    def snapshot(self) -> Any: ...

    def restore(self, state: Any) -> None: ...


class NoTracker:
    """The attacked layer is the tracked objects: the planner reads the perturbed objects themselves,
    one per agent with the agent's id, for a team that brings only a planner (its own tracker's
    output is what it would attack)."""

    def reset(self) -> None:
        """Nothing is kept between frames."""

    def step(self, t: float, detections: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return detections

    def snapshot(self) -> None:
        """No memory to keep."""

    def restore(self, state: None) -> None:
        """No memory to restore."""


def make_tracker(config: TrackerConfig) -> ObjectTracker:
    """The paper's tracker, or none when the errors go in after it (`config.in_loop` false)."""
    return Tracker(config) if config.in_loop else NoTracker()


class Tracker:
    """The paper's tracker between perception and the planner: the attack acts through it, since a
    dropped detection lets a track coast or die and a displaced one drags or splits it. `reset` before
    each rollout; `step` per frame."""

    def __init__(self, config: TrackerConfig = TrackerConfig()) -> None:
        self.config = config
        self._r = np.array([config.position_std**2] * 2 + [config.heading_std**2] * 2)[:, None]  # R's diagonal
        self._p0 = _blocks(np.diag(
            [config.position_std**2] * 2 + [config.initial_velocity_std**2] * 2 + [config.heading_std**2] * 2 + [0.25] * 2
        ))[..., None]
        self._models: dict[float, tuple[np.ndarray, np.ndarray]] = {}  # by the gap rounded to 1e-9 s
        self._model_of_gap: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self.reset()

    def reset(self) -> None:
        """Forget every track; a new rollout starts from here."""
        self.tracks = Tracks(np.zeros(0, np.int64), np.zeros((2, 4, 0)), np.zeros((2, 2, 4, 0)), np.zeros(0),
                             np.zeros((3, 0)))
        self._t = -np.inf
        self._next_id = 1

    def snapshot(self) -> tuple[Tracks, float, int]:
        """Every track and the tracker's time and next id: all a later `step` reads of the frames before
        (the motion models it caches depend on the frame gaps alone)."""
        return self.tracks.copy(), self._t, self._next_id

    def restore(self, state: tuple[Tracks, float, int]) -> None:
        tracks, self._t, self._next_id = state
        self.tracks = tracks.copy()

    def _motion_model(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(F, Q) of one 2x2 block and Q's blocks, for a step of dt, cached: frames come at a fixed
        period. The gaps between frame times differ in their last bits: all that round alike share
        the model of the first of them, found by the gap itself after the first time (cheaper)."""
        model = self._model_of_gap.get(dt)
        if model is None:
            key = round(dt, 9)
            if key not in self._models:
                cfg = self.config
                q_pos = Q_discrete_white_noise(dim=2, dt=dt, var=cfg.accel_std**2, block_size=2, order_by_dim=False)
                q_head = Q_discrete_white_noise(dim=2, dt=dt, var=cfg.heading_accel_std**2, block_size=2, order_by_dim=False)
                self._models[key] = (np.array([[1.0, dt], [0.0, 1.0]]), _blocks(block_diag(q_pos, q_head))[..., None])
            model = self._model_of_gap[dt] = self._models[key]
        return model

    def _predict(self, dt: float) -> None:
        """filterpy's predict for every track: x = Fx, P = FPF' + Q.

        Each product is one matrix product over all blocks, summed as BLAS sums the 8x8 ones
        of the form this replaced (the zeros add nothing): its numbers, to the bit with numpy's
        OpenBLAS, so searches did not change. A lone track's state is the exception kept: numpy
        took the 8x8 product of one state vector as a vector product, which rounds x + dt * v
        twice where a matrix product rounds it once (a fused multiply-add).
        """
        transition, noise = self._motion_model(dt)
        state, covariance = self.tracks.state, self.tracks.covariance
        if len(self.tracks) == 1:
            state[0] += transition[0, 1] * state[1]  # the cached model's dt
        else:
            state[...] = (transition @ state.reshape(2, -1)).reshape(state.shape)
        spread = (transition @ covariance.reshape(2, -1)).reshape(2, 2, -1)
        np.add(np.matmul(transition, spread).reshape(covariance.shape), noise, out=covariance)
        _renormalise_heading(state[0, 2:])

    def _update(self, rows: np.ndarray, z: np.ndarray) -> None:
        """filterpy's update (Joseph form) of the tracks `rows` (ascending) with measurements z (4, M).

        Per 2x2 block: S = HPH' + R is a number, the gain K the block's first column over it, and
        I - KH = [C, (0, 1)'] with C = (1, 0)' - K. Every product of the 8x8 equations is written
        out on the blocks in the order BLAS summed it (one term, or the first then one times the
        second), so the numbers are the 8x8 form's to the bit.
        """
        every = len(rows) == len(self.tracks)  # then rows is 0..N-1: work on the arrays themselves
        x, p = ((self.tracks.state, self.tracks.covariance) if every
                else (np.take(self.tracks.state, rows, axis=-1), np.take(self.tracks.covariance, rows, axis=-1)))
        gain = p[:, 0] * (1.0 / (p[0, 0] + self._r))  # (2, 4, M): the gain of each component and its rate
        x += gain * (z - x[0])
        _renormalise_heading(x[0, 2:])
        c = _FIRST - gain
        left = c[:, None] * p[0]  # (I - KH) P
        left[1] += p[1]
        np.multiply(left[:, 0, None], c, out=p)  # (I - KH) P (I - KH)', where P was
        p[:, 1] += left[:, 1]
        p += (gain * self._r)[:, None] * gain  # + K R K'
        if not every:
            self.tracks.state[..., rows], self.tracks.covariance[..., rows] = x, p

    def _births(self, t: float, det: dict[str, np.ndarray], which: np.ndarray) -> Tracks:
        """New tracks at the detections `which`, velocity included."""
        n = len(which)
        yaw = det["yaw"][which]
        zero = np.zeros(n)
        state = np.array([[det["x"][which], det["y"][which], np.cos(yaw), np.sin(yaw)],
                          [det["vx"][which], det["vy"][which], zero, zero]])
        ids = np.arange(self._next_id, self._next_id + n, dtype=np.int64)
        self._next_id += n
        size = np.array([det["length"][which], det["width"][which], det["height"][which]])
        return Tracks(ids, state, np.repeat(self._p0, n, axis=-1), np.full(n, t), size)

    def step(self, t: float, detections: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Advance to time t with this frame's detections; returns the confirmed tracks.

        Times must not decrease between resets (all tracks share the tracker's time).
        """
        cfg = self.config
        if t < self._t:
            raise ValueError(f"tracker time went back from {self._t} to {t}; reset() starts a new rollout")
        tracks = self.tracks
        if t > self._t and len(tracks):
            self._predict(t - self._t)
        self._t = t

        yaw = detections["yaw"]
        # (7, D): the measurement z = (x, y, cos, sin) and the size of every detection
        det = np.array([detections["x"], detections["y"], np.cos(yaw), np.sin(yaw),
                        detections["length"], detections["width"], detections["height"]])
        rows = cols = _NONE  # matched track and detection indices
        if len(tracks) and det.shape[1]:
            offset = tracks.state[0, :2, :, None] - det[:2, None, :]  # (2, tracks, detections)
            offset *= offset
            rows, cols = _associate(np.sqrt(offset[0] + offset[1]), cfg.gate)
            if rows.size:
                matched = det[:, cols]
                self._update(rows, matched[:4])
                tracks.last_seen[rows] = t
                tracks.size[:, rows] = matched[4:]

        if rows.size < len(tracks):  # only an unobserved track can age out
            keep = t - tracks.last_seen < cfg.max_age - 1e-6
            keep[rows] = True
            if np.count_nonzero(keep) < keep.size:
                self.tracks = self.tracks.select(keep)
        if cols.size < det.shape[1]:
            unmatched = np.ones(det.shape[1], dtype=bool)
            unmatched[cols] = False
            self.tracks = self.tracks.extend(self._births(t, detections, np.flatnonzero(unmatched)))
        return self._output()

    def _output(self) -> dict[str, np.ndarray]:
        n = len(self.tracks)
        rows = np.empty((12, n))  # a copy: the tracker updates its own in place
        rows[:8] = self.tracks.state.reshape(8, n)
        rows[8:11] = self.tracks.size
        rows[11] = np.nan
        return {
            "ids": self.tracks.ids,  # never updated in place
            "x": rows[0],
            "y": rows[1],
            "vx": rows[4],
            "vy": rows[5],
            "yaw": np.arctan2(rows[3], rows[2]),
            "length": rows[8],
            "width": rows[9],
            "height": rows[10],
            "score": rows[11],
        }
