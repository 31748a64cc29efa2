"""The paper's multi-object tracker: Kalman filter per track, Hungarian association.

State per track: position, orientation as (cos, sin) renormalised every step, and their rates,
under a constant-velocity model. Detections measure position and orientation; a new track takes
its velocity from the detection. Association is on centre distance, gated before and after the
assignment. Tracks are confirmed after one observation, coast while unobserved, and are deleted
after `max_age` seconds without an observation.

The filters of all tracks run as one batch: filterpy's KalmanFilter equations (predict
P = FPF' + Q, update with the Joseph form) on (tracks x 8 x 8) arrays, which is what makes a
rollout cheap; test_tracker.py checks the numbers against a filterpy filter per track.

Known property kept on purpose: if a car's detections are dropped and it changes speed, the
coasting track drifts away from where the car reappears; the reappearing detection then spawns a
second track while the first coasts on as a phantom until it ages out. Attacks may exploit it.
"""

from dataclasses import dataclass

import numpy as np
from filterpy.common import Q_discrete_white_noise
from scipy.linalg import block_diag
from scipy.optimize import linear_sum_assignment

# state layout: x, y, vx, vy, c, s, vc, vs  (c, s) = (cos yaw, sin yaw)
_MEASURED = np.array([0, 1, 4, 5])
_UNASSIGNABLE = 1e9
_NONE = np.zeros(0, dtype=np.int64)


@dataclass(frozen=True)
class TrackerConfig:
    gate: float = 2.0  # m, centre distance, applied before and after assignment
    max_age: float = 1.0  # s without an observation before a track is deleted
    position_std: float = 0.3  # m, measurement noise
    heading_std: float = 0.1  # measurement noise on cos/sin
    accel_std: float = 2.0  # m/s^2, white-acceleration process noise
    heading_accel_std: float = 1.0  # 1/s^2 on cos/sin
    initial_velocity_std: float = 0.5  # m/s, trust in the detection's velocity


@dataclass(frozen=True)
class Tracks:
    """Every live track, in creation order (association ties follow this order).

    The tracker updates state, covariance, last_seen and size in place (never ids), so
    `Tracker.step` hands out copies of those.
    """

    ids: np.ndarray  # (N,) int64
    state: np.ndarray  # (N, 8) in the layout above, at the tracker's time
    covariance: np.ndarray  # (N, 8, 8)
    last_seen: np.ndarray  # (N,) time of the last observation
    size: np.ndarray  # (N, 3) length, width, height of the last observation

    def __len__(self) -> int:
        return len(self.ids)

    def select(self, keep: np.ndarray) -> "Tracks":
        return Tracks(self.ids[keep], self.state[keep], self.covariance[keep], self.last_seen[keep], self.size[keep])

    def extend(self, other: "Tracks") -> "Tracks":
        return Tracks(*(np.concatenate([mine, theirs]) for mine, theirs in zip(self._arrays(), other._arrays())))

    def _arrays(self) -> tuple[np.ndarray, ...]:
        return self.ids, self.state, self.covariance, self.last_seen, self.size


def _transition(dt: float) -> np.ndarray:
    block = np.eye(4)
    block[0, 2] = block[1, 3] = dt
    return block_diag(block, block)


def _renormalise_heading(state: np.ndarray) -> None:
    """(cos, sin) back onto the unit circle, in place; a vanishing vector is left alone (divided by
    1, exactly itself: cheaper than np.divide's where=)."""
    norm = np.hypot(state[:, 4], state[:, 5])
    state[:, 4:6] /= np.where(norm > 1e-9, norm, 1.0)[:, None]


class Tracker:
    def __init__(self, config: TrackerConfig = TrackerConfig()) -> None:
        self.config = config
        self._r_diag = np.array([config.position_std**2] * 2 + [config.heading_std**2] * 2)
        self._h = np.zeros((4, 8))
        self._h[np.arange(4), _MEASURED] = 1.0
        self._eye = np.eye(8)
        self._p0 = np.diag(
            [config.position_std**2] * 2 + [config.initial_velocity_std**2] * 2 + [config.heading_std**2] * 2 + [0.25] * 2
        )
        self._models: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self.reset()

    def reset(self) -> None:
        """Forget every track; a new rollout starts from here."""
        self.tracks = Tracks(np.zeros(0, np.int64), np.zeros((0, 8)), np.zeros((0, 8, 8)), np.zeros(0), np.zeros((0, 3)))
        self._t = -np.inf
        self._next_id = 1

    def _motion_model(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(F, Q) for a step of dt, cached: frames come at a fixed period."""
        key = round(dt, 9)
        if key not in self._models:
            cfg = self.config
            q_pos = Q_discrete_white_noise(dim=2, dt=dt, var=cfg.accel_std**2, block_size=2, order_by_dim=False)
            q_head = Q_discrete_white_noise(dim=2, dt=dt, var=cfg.heading_accel_std**2, block_size=2, order_by_dim=False)
            self._models[key] = (_transition(dt), block_diag(q_pos, q_head))
        return self._models[key]

    def _predict(self, dt: float) -> None:
        """filterpy's predict for every track: x = Fx, P = FPF' + Q."""
        transition, noise = self._motion_model(dt)
        state, covariance = self.tracks.state, self.tracks.covariance
        np.matmul(state, transition.T, out=state)
        np.matmul(transition @ covariance, transition.T, out=covariance)
        covariance += noise
        _renormalise_heading(state)

    def _update(self, rows: np.ndarray, z: np.ndarray) -> None:
        """filterpy's update (Joseph form) of the tracks `rows` (ascending) with measurements z (M, 4).

        S = HPH' + R is diagonal, exactly: F, Q and P0 never correlate x, y, cos and sin with one
        another (each only with its own rate), and neither does an update. So S^-1 is 1 / diag(S).
        """
        every = len(rows) == len(self.tracks)  # then rows is 0..N-1: work on the arrays themselves
        x, p = (self.tracks.state, self.tracks.covariance) if every else (self.tracks.state[rows], self.tracks.covariance[rows])
        pht = p[:, :, _MEASURED]  # P H': H only selects the measured components
        gain = pht * (1.0 / (p[:, _MEASURED, _MEASURED] + self._r_diag))[:, None, :]
        x += (gain @ (z - x[:, _MEASURED])[:, :, None])[:, :, 0]
        i_kh = self._eye - gain @ self._h
        np.matmul(i_kh @ p, i_kh.transpose(0, 2, 1), out=p)
        p += (gain * self._r_diag) @ gain.transpose(0, 2, 1)
        _renormalise_heading(x)
        if not every:
            self.tracks.state[rows], self.tracks.covariance[rows] = x, p

    def _births(self, t: float, det: dict[str, np.ndarray], which: np.ndarray) -> Tracks:
        """New tracks at the detections `which`, velocity included."""
        n = len(which)
        yaw = det["yaw"][which]
        zero = np.zeros(n)
        state = np.array([det["x"][which], det["y"][which], det["vx"][which], det["vy"][which], np.cos(yaw), np.sin(yaw), zero, zero])
        ids = np.arange(self._next_id, self._next_id + n, dtype=np.int64)
        self._next_id += n
        size = np.array([det["length"][which], det["width"][which], det["height"][which]])
        return Tracks(ids, state.T.copy(), np.repeat(self._p0[None], n, axis=0), np.full(n, t), size.T.copy())

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
            dx = tracks.state[:, 0, None] - det[0]
            dy = tracks.state[:, 1, None] - det[1]
            cost = np.sqrt(dx * dx + dy * dy)
            gated = cost <= cfg.gate
            rows, cols = linear_sum_assignment(np.where(gated, cost, _UNASSIGNABLE))
            ok = gated[rows, cols]
            if not ok.all():
                rows, cols = rows[ok], cols[ok]
            if rows.size:
                matched = det[:, cols].T
                self._update(rows, matched[:, :4])
                tracks.last_seen[rows] = t
                tracks.size[rows] = matched[:, 4:]

        if rows.size < len(tracks):  # only an unobserved track can age out
            keep = t - tracks.last_seen < cfg.max_age - 1e-6
            keep[rows] = True
            if not keep.all():
                self.tracks = self.tracks.select(keep)
        if cols.size < det.shape[1]:
            unmatched = np.ones(det.shape[1], dtype=bool)
            unmatched[cols] = False
            self.tracks = self.tracks.extend(self._births(t, detections, np.flatnonzero(unmatched)))
        return self._output()

    def _output(self) -> dict[str, np.ndarray]:
        columns = np.concatenate([self.tracks.state.T, self.tracks.size.T])  # a copy: the tracker updates its own in place
        return {
            "ids": self.tracks.ids,  # never updated in place
            "x": columns[0],
            "y": columns[1],
            "vx": columns[2],
            "vy": columns[3],
            "yaw": np.arctan2(columns[5], columns[4]),
            "length": columns[8],
            "width": columns[9],
            "height": columns[10],
            "score": np.full(len(self.tracks), np.nan),
        }
