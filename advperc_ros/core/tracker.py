"""The paper's multi-object tracker: Kalman filter per track, Hungarian association.

State per track: position, orientation as (cos, sin) renormalised every step, and their rates,
under a constant-velocity model. Detections measure position and orientation; a new track takes
its velocity from the detection. Association is on centre distance, gated before and after the
assignment. Tracks are confirmed after one observation, coast while unobserved, and are deleted
after `max_age` seconds without an observation.

Known property kept on purpose: if a car's detections are dropped and it changes speed, the
coasting track drifts away from where the car reappears; the reappearing detection then spawns a
second track while the first coasts on as a phantom until it ages out. Attacks may exploit it.
"""

from dataclasses import dataclass

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter
from scipy.linalg import block_diag
from scipy.optimize import linear_sum_assignment

# state layout: x, y, vx, vy, c, s, vc, vs  (c, s) = (cos yaw, sin yaw)
_MEASURED = np.array([0, 1, 4, 5])
_UNASSIGNABLE = 1e9


@dataclass(frozen=True)
class TrackerConfig:
    gate: float = 2.0  # m, centre distance, applied before and after assignment
    max_age: float = 1.0  # s without an observation before a track is deleted
    position_std: float = 0.3  # m, measurement noise
    heading_std: float = 0.1  # measurement noise on cos/sin
    accel_std: float = 2.0  # m/s^2, white-acceleration process noise
    heading_accel_std: float = 1.0  # 1/s^2 on cos/sin
    initial_velocity_std: float = 0.5  # m/s, trust in the detection's velocity


@dataclass
class _Track:
    id: int
    kf: KalmanFilter
    t: float
    last_seen: float
    size: np.ndarray  # length, width, height


def _transition(dt: float) -> np.ndarray:
    block = np.eye(4)
    block[0, 2] = block[1, 3] = dt
    return block_diag(block, block)


def _renormalise_heading(kf: KalmanFilter) -> None:
    norm = np.hypot(kf.x[4, 0], kf.x[5, 0])
    if norm > 1e-9:
        kf.x[4:6, 0] /= norm


class Tracker:
    def __init__(self, config: TrackerConfig = TrackerConfig()) -> None:
        self.config = config
        self._r = np.diag([config.position_std**2] * 2 + [config.heading_std**2] * 2)
        self._h = np.zeros((4, 8))
        self._h[np.arange(4), _MEASURED] = 1.0
        self._models: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self.reset()

    def reset(self) -> None:
        """Forget every track; a new rollout starts from here."""
        self._tracks: list[_Track] = []
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

    def _spawn(self, t: float, det: dict[str, np.ndarray], i: int) -> None:
        cfg = self.config
        kf = KalmanFilter(dim_x=8, dim_z=4)
        kf.H = self._h
        kf.R = self._r
        c, s = np.cos(det["yaw"][i]), np.sin(det["yaw"][i])
        kf.x = np.array([[det["x"][i]], [det["y"][i]], [det["vx"][i]], [det["vy"][i]], [c], [s], [0.0], [0.0]])
        kf.P = np.diag(
            [cfg.position_std**2] * 2 + [cfg.initial_velocity_std**2] * 2 + [cfg.heading_std**2] * 2 + [0.25] * 2
        )
        size = np.array([det["length"][i], det["width"][i], det["height"][i]])
        self._tracks.append(_Track(id=self._next_id, kf=kf, t=t, last_seen=t, size=size))
        self._next_id += 1

    def step(self, t: float, detections: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Advance to time t with this frame's detections; returns the confirmed tracks."""
        cfg = self.config
        for track in self._tracks:
            dt = t - track.t
            if dt > 0.0:
                transition, noise = self._motion_model(dt)
                track.kf.predict(F=transition, Q=noise)
                _renormalise_heading(track.kf)
                track.t = t

        num_det = len(detections["x"])
        matched_tracks: set[int] = set()
        matched_dets: set[int] = set()
        if self._tracks and num_det:
            predicted = np.array([[tr.kf.x[0, 0], tr.kf.x[1, 0]] for tr in self._tracks])
            measured = np.stack([detections["x"], detections["y"]], axis=1)
            cost = np.linalg.norm(predicted[:, None, :] - measured[None, :, :], axis=2)
            gated = np.where(cost <= cfg.gate, cost, _UNASSIGNABLE)
            for ti, di in zip(*linear_sum_assignment(gated)):
                if cost[ti, di] > cfg.gate:
                    continue
                track = self._tracks[ti]
                yaw = detections["yaw"][di]
                z = np.array([[detections["x"][di]], [detections["y"][di]], [np.cos(yaw)], [np.sin(yaw)]])
                track.kf.update(z)
                _renormalise_heading(track.kf)
                track.last_seen = t
                track.size = np.array([detections["length"][di], detections["width"][di], detections["height"][di]])
                matched_tracks.add(ti)
                matched_dets.add(di)

        self._tracks = [
            tr for ti, tr in enumerate(self._tracks) if ti in matched_tracks or t - tr.last_seen < cfg.max_age - 1e-6
        ]
        for di in range(num_det):
            if di not in matched_dets:
                self._spawn(t, detections, di)
        return self._output()

    def _output(self) -> dict[str, np.ndarray]:
        states = np.array([tr.kf.x[:, 0] for tr in self._tracks]).reshape(-1, 8)
        sizes = np.array([tr.size for tr in self._tracks]).reshape(-1, 3)
        return {
            "ids": np.array([tr.id for tr in self._tracks], dtype=np.int64),
            "x": states[:, 0],
            "y": states[:, 1],
            "vx": states[:, 2],
            "vy": states[:, 3],
            "yaw": np.arctan2(states[:, 5], states[:, 4]),
            "length": sizes[:, 0],
            "width": sizes[:, 1],
            "height": sizes[:, 2],
            "score": np.full(len(self._tracks), np.nan),
        }
