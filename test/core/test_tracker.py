"""The Kalman + Hungarian tracker: association, gating, coasting, ageing, heading,
and its batched filter against a filterpy KalmanFilter per track."""

import numpy as np
import pytest
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter
from scipy.linalg import block_diag
from scipy.optimize import linear_sum_assignment

from advperc_ros.core.geometry import wrap_angle
from advperc_ros.core.tracker import Tracker, TrackerConfig, _associate

DT = 0.1


def dets(*boxes):
    """Detections from (x, y, yaw, vx, vy) tuples; size 4.5 x 1.9 x 1.6."""
    arr = np.array(boxes, dtype=float).reshape(-1, 5)
    n = arr.shape[0]
    return {
        "ids": np.arange(n, dtype=np.int64),
        "x": arr[:, 0],
        "y": arr[:, 1],
        "yaw": arr[:, 2],
        "vx": arr[:, 3],
        "vy": arr[:, 4],
        "length": np.full(n, 4.5),
        "width": np.full(n, 1.9),
        "height": np.full(n, 1.6),
        "score": np.linspace(0.9, 0.5, n) if n else np.zeros(0),
    }


NONE = dets()


def by_id(tracks, track_id):
    i = np.flatnonzero(tracks["ids"] == track_id)
    assert i.size == 1, f"track {track_id} not in output {tracks['ids']}"
    return {k: v[i[0]] for k, v in tracks.items()}


def t_of(k):
    return k * DT


# ---------------------------------------------------------------- a single car

def test_constant_velocity_car_keeps_its_id_and_converges():
    tracker = Tracker()
    v = np.array([8.0, 1.0])
    yaw = np.arctan2(v[1], v[0])
    for k in range(60):
        pos = np.array([3.0, -2.0]) + v * t_of(k)
        # the first detection reports no velocity, so the filter must learn it from positions
        reported = (0.0, 0.0) if k == 0 else tuple(v)
        out = tracker.step(t_of(k), dets((pos[0], pos[1], yaw, *reported)))
        assert list(out["ids"]) == [1]
    track = by_id(out, 1)
    assert np.hypot(track["x"] - pos[0], track["y"] - pos[1]) < 0.05
    assert np.hypot(track["vx"] - v[0], track["vy"] - v[1]) < 0.1
    assert abs(wrap_angle(track["yaw"] - yaw)) < 1e-3
    assert (track["length"], track["width"], track["height"]) == (4.5, 1.9, 1.6)
    assert np.isnan(track["score"])


def test_new_track_takes_velocity_and_pose_from_the_detection():
    tracker = Tracker()
    out = tracker.step(0.0, dets((10.0, 5.0, 0.5, 7.0, -3.0)))
    track = by_id(out, 1)
    assert (track["x"], track["y"], track["vx"], track["vy"]) == pytest.approx((10.0, 5.0, 7.0, -3.0))
    assert track["yaw"] == pytest.approx(0.5)
    # unobserved next frame: it coasts with that velocity
    out = tracker.step(0.1, NONE)
    track = by_id(out, 1)
    assert (track["x"], track["y"]) == pytest.approx((10.7, 4.7))


def test_association_is_gated_at_two_metres():
    tracker = Tracker()
    tracker.step(0.0, dets((0.0, 0.0, 0.0, 0.0, 0.0)))
    # 1.9 m from the (stationary) prediction: same track
    out = tracker.step(0.1, dets((0.0, 1.9, 0.0, 0.0, 0.0)))
    assert list(out["ids"]) == [1]
    # 2.5 m from the prediction: a new track, the old one coasts
    pred = by_id(out, 1)
    out = tracker.step(0.2, dets((pred["x"] + pred["vx"] * 0.1 + 2.5, pred["y"] + pred["vy"] * 0.1, 0.0, 0.0, 0.0)))
    assert sorted(out["ids"]) == [1, 2]
    assert by_id(out, 2)["x"] == pytest.approx(pred["x"] + pred["vx"] * 0.1 + 2.5)


def test_gate_is_configurable():
    tracker = Tracker(TrackerConfig(gate=3.0))
    tracker.step(0.0, dets((0.0, 0.0, 0.0, 0.0, 0.0)))
    out = tracker.step(0.1, dets((2.5, 0.0, 0.0, 0.0, 0.0)))
    assert list(out["ids"]) == [1]


def test_coasting_then_deleted_after_max_age():
    """Unobserved for < 1 s: still output, moving at its velocity. Deleted when t - last_seen >= max_age,
    i.e. at the 10th unobserved frame at 10 Hz."""
    tracker = Tracker()
    v = 10.0
    last_seen = 20
    for k in range(last_seen + 1):
        out = tracker.step(t_of(k), dets((v * t_of(k), 0.0, 0.0, v, 0.0)))
    x_last = by_id(out, 1)["x"]
    for k in range(last_seen + 1, last_seen + 10):
        out = tracker.step(t_of(k), NONE)
        track = by_id(out, 1)
        assert track["x"] == pytest.approx(x_last + v * (t_of(k) - t_of(last_seen)), abs=1e-6)
        assert track["vx"] == pytest.approx(v, abs=1e-6)
    out = tracker.step(t_of(last_seen + 10), NONE)
    assert out["ids"].size == 0
    assert out["x"].shape == (0,)
    # a later detection starts a fresh id
    out = tracker.step(t_of(last_seen + 11), dets((0.0, 0.0, 0.0, 0.0, 0.0)))
    assert list(out["ids"]) == [2]


def test_max_age_is_configurable():
    tracker = Tracker(TrackerConfig(max_age=0.5))
    tracker.step(0.0, dets((0.0, 0.0, 0.0, 0.0, 0.0)))
    for k in range(1, 5):
        assert list(tracker.step(t_of(k), NONE)["ids"]) == [1]
    assert tracker.step(t_of(5), NONE)["ids"].size == 0


def test_observation_refreshes_age():
    tracker = Tracker()
    tracker.step(0.0, dets((0.0, 0.0, 0.0, 0.0, 0.0)))
    for k in range(1, 40):
        # observed every 9th frame: never 10 frames without an observation
        out = tracker.step(t_of(k), dets((0.0, 0.0, 0.0, 0.0, 0.0)) if k % 9 == 0 else NONE)
        assert list(out["ids"]) == [1]


# ---------------------------------------------------------------- heading

def test_heading_renormalised_and_stable_near_pi():
    """A westbound car weaving around yaw = +-pi, its detected yaw jumping across the wrap: (cos, sin)
    stays on the unit circle and the tracked yaw follows without flipping."""
    tracker = Tracker()
    rng = np.random.default_rng(2)
    speed, x, errors = 6.0, 0.0, []
    for k in range(80):
        yaw = float(wrap_angle(np.pi + 0.3 * np.sin(0.1 * k)))
        measured = float(wrap_angle(yaw + rng.uniform(-0.02, 0.02)))
        out = tracker.step(t_of(k), dets((x, 0.0, measured, speed * np.cos(yaw), speed * np.sin(yaw))))
        x += speed * np.cos(yaw) * DT
        assert list(out["ids"]) == [1]
        errors.append(abs(float(wrap_angle(by_id(out, 1)["yaw"] - yaw))))
        cos, sin = tracker.tracks.state[0, 2:, 0]
        assert np.hypot(cos, sin) == pytest.approx(1.0, abs=1e-12)
    assert max(errors) < 0.1
    # and while coasting (the predicted heading rate would otherwise shrink or grow the vector)
    for k in range(80, 85):
        tracker.step(t_of(k), NONE)
        cos, sin = tracker.tracks.state[0, 2:, 0]
        assert np.hypot(cos, sin) == pytest.approx(1.0, abs=1e-12)


def test_heading_noise_across_the_wrap_does_not_flip():
    tracker = Tracker()
    for k in range(30):
        measured = np.pi - 0.02 if k % 2 else -np.pi + 0.02
        out = tracker.step(t_of(k), dets((-5.0 * t_of(k), 0.0, measured, -5.0, 0.0)))
        assert abs(float(wrap_angle(by_id(out, 1)["yaw"] - np.pi))) < 0.03


def test_turning_car_heading_followed():
    tracker = Tracker()
    rate = 0.5  # rad/s, a left turn through +-pi
    for k in range(80):
        yaw = float(wrap_angle(2.5 + rate * t_of(k)))
        pos = 10.0 * np.array([np.sin(2.5 + rate * t_of(k)), -np.cos(2.5 + rate * t_of(k))])  # circle radius 10
        v = 5.0 * np.array([np.cos(yaw), np.sin(yaw)])
        out = tracker.step(t_of(k), dets((pos[0], pos[1], yaw, v[0], v[1])))
        assert list(out["ids"]) == [1]
        assert abs(float(wrap_angle(by_id(out, 1)["yaw"] - yaw))) < 0.1


# ---------------------------------------------------------------- the documented phantom

def test_dropped_braking_car_spawns_second_track_and_phantom_ages_out():
    tracker = Tracker()
    v0, decel = 15.0, 8.0
    last_seen, reappear = 20, 29  # frames 21..28 dropped: 0.8 s without detections

    def car(k):
        """Constant speed until frame 20, brakes at 8 m/s^2 for 0.8 s, then constant speed again."""
        tau = np.clip(t_of(k) - t_of(last_seen), 0.0, 0.8)  # time spent braking so far
        after = max(t_of(k) - t_of(last_seen) - 0.8, 0.0)  # time since braking ended
        speed = v0 - decel * tau
        x = v0 * min(t_of(k), t_of(last_seen)) + v0 * tau - 0.5 * decel * tau**2 + speed * after
        return x, speed

    for k in range(last_seen + 1):
        x, speed = car(k)
        out = tracker.step(t_of(k), dets((x, 0.0, 0.0, speed, 0.0)))
    assert list(out["ids"]) == [1]
    x_last = by_id(out, 1)["x"]
    for k in range(last_seen + 1, reappear):
        out = tracker.step(t_of(k), NONE)
        assert list(out["ids"]) == [1]
    x, speed = car(reappear)
    coast = x_last + v0 * (t_of(reappear) - t_of(last_seen))
    assert coast - x > 2.0  # the car is out of the coasting track's gate
    out = tracker.step(t_of(reappear), dets((x, 0.0, 0.0, speed, 0.0)))
    assert sorted(out["ids"]) == [1, 2]
    assert by_id(out, 1)["x"] == pytest.approx(coast, abs=1e-6)  # the phantom, still coasting
    assert by_id(out, 2)["x"] == pytest.approx(x)
    assert by_id(out, 2)["vx"] == pytest.approx(speed)
    # the phantom goes once unobserved for max_age (1 s after frame 20: frame 30)
    x, speed = car(reappear + 1)
    out = tracker.step(t_of(reappear + 1), dets((x, 0.0, 0.0, speed, 0.0)))
    assert list(out["ids"]) == [2]
    for k in range(reappear + 2, reappear + 20):
        x, speed = car(k)
        out = tracker.step(t_of(k), dets((x, 0.0, 0.0, speed, 0.0)))
        assert list(out["ids"]) == [2]


def test_short_drop_without_speed_change_keeps_one_track():
    tracker = Tracker()
    for k in range(40):
        observed = not (20 < k < 29)
        out = tracker.step(t_of(k), dets((15.0 * t_of(k), 0.0, 0.0, 15.0, 0.0)) if observed else NONE)
        assert list(out["ids"]) == [1]


# ---------------------------------------------------------------- two cars

def _greedy_nearest(cost, gate):
    """Globally-nearest-pair-first greedy assignment."""
    pairs, used_t, used_d = [], set(), set()
    for flat in np.argsort(cost, axis=None):
        ti, di = np.unravel_index(flat, cost.shape)
        if ti in used_t or di in used_d or cost[ti, di] > gate:
            continue
        pairs.append((int(ti), int(di)))
        used_t.add(ti)
        used_d.add(di)
    return sorted(pairs)


def test_crossing_cars_keep_ids_where_greedy_would_swap():
    """Car A eastbound, car B northbound crossing 2 m ahead of A. At t = 1 s both detections are off by
    about a metre so that the nearest pair is (track B, detection of A): greedy nearest neighbour swaps
    the cars, the Hungarian assignment does not."""
    tracker = Tracker()

    def car_a(t):
        return np.array([5.0 * (t - 1.0), 0.0]), 0.0, (5.0, 0.0)

    def car_b(t):
        return np.array([2.0, 5.0 * (t - 1.0)]), np.pi / 2, (0.0, 5.0)

    def exact(t):
        (pa, ya, va), (pb, yb, vb) = car_a(t), car_b(t)
        return dets((pa[0], pa[1], ya, *va), (pb[0], pb[1], yb, *vb))

    for k in range(10):
        out = tracker.step(t_of(k), exact(t_of(k)))
    assert sorted(out["ids"]) == [1, 2]
    # id 1 is A (first detection), id 2 is B
    pred = {i: np.array([by_id(out, i)["x"], by_id(out, i)["y"]]) + DT * np.array([by_id(out, i)["vx"], by_id(out, i)["vy"]])
            for i in (1, 2)}
    np.testing.assert_allclose(pred[1], [0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(pred[2], [2.0, 0.0], atol=1e-6)
    noisy_a, noisy_b = np.array([1.2, 0.0]), np.array([1.6, 1.0])
    cost = np.array([[np.linalg.norm(pred[i] - d) for d in (noisy_a, noisy_b)] for i in (1, 2)])
    assert _greedy_nearest(cost, 2.0) == [(0, 1), (1, 0)]  # greedy would swap the cars
    out = tracker.step(t_of(10), dets((*noisy_a, 0.0, 5.0, 0.0), (*noisy_b, np.pi / 2, 0.0, 5.0)))
    assert sorted(out["ids"]) == [1, 2]
    a1, b2 = by_id(out, 1), by_id(out, 2)
    assert np.hypot(a1["x"] - noisy_a[0], a1["y"] - noisy_a[1]) < np.hypot(a1["x"] - noisy_b[0], a1["y"] - noisy_b[1])
    assert np.hypot(b2["x"] - noisy_b[0], b2["y"] - noisy_b[1]) < np.hypot(b2["x"] - noisy_a[0], b2["y"] - noisy_a[1])
    for k in range(11, 30):
        out = tracker.step(t_of(k), exact(t_of(k)))
        assert sorted(out["ids"]) == [1, 2]
    pa, pb = car_a(t_of(29))[0], car_b(t_of(29))[0]
    assert np.hypot(by_id(out, 1)["x"] - pa[0], by_id(out, 1)["y"] - pa[1]) < 0.5
    assert np.hypot(by_id(out, 2)["x"] - pb[0], by_id(out, 2)["y"] - pb[1]) < 0.5


def test_association_without_solving_when_unambiguous_equals_the_hungarian_one():
    """Gated pairs that share no track and no detection are taken as they are; the rest is solved."""
    rng = np.random.default_rng(5)
    for case in range(3000):
        cost = rng.uniform(0.0, rng.choice([2.5, 6.0, 30.0]), rng.integers(1, 9, 2))
        if case % 3 == 0:  # tracks exactly on a detection's gate
            cost[rng.random(cost.shape) < 0.2] = 2.0
        gated = cost <= 2.0
        rows, cols = linear_sum_assignment(np.where(gated, cost, 1e9))
        ok = gated[rows, cols]
        got_rows, got_cols = _associate(cost, 2.0)
        assert got_rows.tolist() == rows[ok].tolist() and got_cols.tolist() == cols[ok].tolist(), case


def test_two_detections_one_track_spawns_only_for_the_unmatched():
    tracker = Tracker()
    tracker.step(0.0, dets((0.0, 0.0, 0.0, 0.0, 0.0)))
    out = tracker.step(0.1, dets((30.0, 0.0, 0.0, 0.0, 0.0), (0.5, 0.0, 0.0, 0.0, 0.0)))
    assert sorted(out["ids"]) == [1, 2]
    assert by_id(out, 2)["x"] == pytest.approx(30.0)
    assert abs(by_id(out, 1)["x"] - 0.5) < 0.5


def test_reset_forgets_everything():
    tracker = Tracker()
    for k in range(5):
        tracker.step(t_of(k), dets((k, 0.0, 0.0, 10.0, 0.0), (k, 10.0, 0.0, 10.0, 0.0)))
    tracker.reset()
    out = tracker.step(0.0, NONE)
    assert out["ids"].size == 0
    out = tracker.step(0.0, dets((100.0, 0.0, 0.0, 0.0, 0.0)))
    assert list(out["ids"]) == [1]
    assert by_id(out, 1)["x"] == pytest.approx(100.0)


# ---------------------------------------------------------------- the batched filter against filterpy

class FilterpyTracker:
    """The tracker as it was before it was batched: one filterpy KalmanFilter per track, the same rules."""

    def __init__(self, cfg: TrackerConfig = TrackerConfig()) -> None:
        self.cfg, self.tracks, self.next_id = cfg, [], 1

    def step(self, t, det):
        cfg = self.cfg
        for tr in self.tracks:
            dt = t - tr["t"]
            if dt > 0.0:
                block = np.eye(4)
                block[0, 2] = block[1, 3] = dt
                q_pos = Q_discrete_white_noise(dim=2, dt=dt, var=cfg.accel_std**2, block_size=2, order_by_dim=False)
                q_head = Q_discrete_white_noise(dim=2, dt=dt, var=cfg.heading_accel_std**2, block_size=2, order_by_dim=False)
                tr["kf"].predict(F=block_diag(block, block), Q=block_diag(q_pos, q_head))
                self._renormalise(tr["kf"])
                tr["t"] = t
        matched_t, matched_d = set(), set()
        if self.tracks and len(det["x"]):
            predicted = np.array([tr["kf"].x[:2, 0] for tr in self.tracks])
            cost = np.hypot(predicted[:, None, 0] - det["x"][None], predicted[:, None, 1] - det["y"][None])
            for ti, di in zip(*linear_sum_assignment(np.where(cost <= cfg.gate, cost, 1e9))):
                if cost[ti, di] <= cfg.gate:
                    tr, yaw = self.tracks[ti], det["yaw"][di]
                    tr["kf"].update(np.array([[det["x"][di]], [det["y"][di]], [np.cos(yaw)], [np.sin(yaw)]]))
                    self._renormalise(tr["kf"])
                    tr["last_seen"] = t
                    matched_t.add(ti)
                    matched_d.add(di)
        self.tracks = [tr for ti, tr in enumerate(self.tracks) if ti in matched_t or t - tr["last_seen"] < cfg.max_age - 1e-6]
        for di in sorted(set(range(len(det["x"]))) - matched_d):
            kf = KalmanFilter(dim_x=8, dim_z=4)
            kf.H = np.zeros((4, 8))
            kf.H[[0, 1, 2, 3], [0, 1, 4, 5]] = 1.0
            kf.R = np.diag([cfg.position_std**2] * 2 + [cfg.heading_std**2] * 2)
            yaw = det["yaw"][di]
            kf.x = np.array([[det["x"][di]], [det["y"][di]], [det["vx"][di]], [det["vy"][di]], [np.cos(yaw)], [np.sin(yaw)], [0.0], [0.0]])
            kf.P = np.diag([cfg.position_std**2] * 2 + [cfg.initial_velocity_std**2] * 2 + [cfg.heading_std**2] * 2 + [0.25] * 2)
            self.tracks.append({"id": self.next_id, "kf": kf, "t": t, "last_seen": t})
            self.next_id += 1

    @staticmethod
    def _renormalise(kf):
        norm = np.hypot(kf.x[4, 0], kf.x[5, 0])
        if norm > 1e-9:
            kf.x[4:6, 0] /= norm


def random_traffic(seed, frames=150):
    """Detections of cars that appear, vanish, reappear, turn, brake and cross, with noise and clutter.

    Each car has its own drop pattern: single-frame misses, drops shorter and longer than max_age;
    clutter detections appear for a frame or two and are never seen again.
    """
    rng = np.random.default_rng(seed)
    num_cars = 6
    start = rng.uniform(-40.0, 40.0, (num_cars, 2))
    heading = rng.uniform(-np.pi, np.pi, num_cars)
    speed = rng.uniform(0.0, 15.0, num_cars)
    turn = rng.choice([0.0, 0.0, 0.3, -0.5], num_cars)
    accel = rng.choice([0.0, -3.0, 1.5], num_cars)
    # two cars through the origin from crossing directions, both at 4 s
    heading[1] = heading[0] + np.pi / 2
    speed[1] = speed[0] = 8.0
    turn[:2] = accel[:2] = 0.0
    start[0] = -4.0 * np.array([np.cos(heading[0]), np.sin(heading[0])]) * 8.0
    start[1] = -4.0 * np.array([np.cos(heading[1]), np.sin(heading[1])]) * 8.0
    present = np.ones((frames, num_cars), dtype=bool)
    for j in range(num_cars):
        present[: rng.integers(0, 40) if j >= 2 else 0, j] = False  # births at different frames
        for _ in range(rng.integers(1, 5)):
            a = rng.integers(0, frames)
            present[a : a + rng.choice([1, 3, 8, 15]), j] = False  # drops, some longer than max_age
    yaw, spd = heading.copy(), speed.copy()
    pos = start.copy()
    out = []
    for k in range(frames):
        boxes = []
        for j in range(num_cars):
            if present[k, j]:
                v = spd[j] * np.array([np.cos(yaw[j]), np.sin(yaw[j])])
                noisy = pos[j] + rng.normal(0.0, 0.2, 2)
                boxes.append((*noisy, wrap_angle(yaw[j] + rng.normal(0.0, 0.03)), *v))
        for _ in range(rng.poisson(0.3)):
            boxes.append((*rng.uniform(-60.0, 60.0, 2), rng.uniform(-np.pi, np.pi), *rng.normal(0.0, 3.0, 2)))
        order = rng.permutation(len(boxes))
        out.append(dets(*[boxes[i] for i in order]) if boxes else NONE)
        pos += DT * spd[:, None] * np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
        yaw = wrap_angle(yaw + DT * turn)
        spd = np.maximum(spd + DT * accel, 0.0)
    return out


PAIRS = np.array([[0, 2], [1, 3], [4, 6], [5, 7]])  # a measured component and its rate, in filterpy's layout
IN_BLOCKS = np.zeros((8, 8), dtype=bool)
for _pair in PAIRS:
    IN_BLOCKS[_pair[:, None], _pair[None, :]] = True


def filterpy_layout(tracks):
    """(N, 8) states and (N, 8, 8) covariances of the tracker's blocks, in filterpy's layout (x, y,
    vx, vy, c, s, vc, vs), zeros between components."""
    n = len(tracks)
    state, covariance = np.zeros((n, 8)), np.zeros((n, 8, 8))
    for m, pair in enumerate(PAIRS):
        state[:, pair] = tracks.state[:, m].T
        covariance[:, pair[:, None], pair[None, :]] = tracks.covariance[:, :, m].transpose(2, 0, 1)
    return state, covariance


def assert_same_as_filterpy(frames, times, config=TrackerConfig()):
    """Steps both trackers through the frames, comparing at every step; returns (births, deletions, most at once)."""
    ours, ref = Tracker(config), FilterpyTracker(config)
    live, deletions, most = set(), 0, 0
    for t, frame in zip(times, frames):
        out = ours.step(t, frame)
        ref.step(t, frame)
        assert list(out["ids"]) == [tr["id"] for tr in ref.tracks]
        deletions += len(live - set(out["ids"]))
        live, most = set(out["ids"]), max(most, len(out["ids"]))
        if not ref.tracks:
            continue
        state = np.array([tr["kf"].x[:, 0] for tr in ref.tracks])
        covariance = np.array([tr["kf"].P for tr in ref.tracks])
        assert not covariance[:, ~IN_BLOCKS].any()  # exactly: what lets the tracker keep the blocks alone
        our_state, our_covariance = filterpy_layout(ours.tracks)
        np.testing.assert_allclose(our_state, state, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(our_covariance, covariance, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(out["x"], state[:, 0], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(out["vy"], state[:, 3], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(out["yaw"], np.arctan2(state[:, 5], state[:, 4]), rtol=1e-12, atol=1e-12)
    return ref.next_id - 1, deletions, most


@pytest.mark.parametrize("seed", range(6))
def test_batched_filter_equals_filterpy_per_track(seed):
    frames = random_traffic(seed)
    births, deletions, most = assert_same_as_filterpy(frames, [t_of(k) for k in range(len(frames))])
    assert births > 20 and deletions > 20 and most >= 8  # the traffic exercised what it should


def test_batched_filter_equals_filterpy_with_irregular_steps_and_repeated_times():
    frames = random_traffic(11, frames=80)
    times = np.cumsum(np.random.default_rng(3).choice([0.0, 0.05, 0.1, 0.1, 0.23], len(frames)))
    assert_same_as_filterpy(frames, times, TrackerConfig(gate=3.0, max_age=0.6))


def test_batched_filter_equals_filterpy_for_a_lone_track():
    """One track takes its own path through the prediction (a vector product in the 8x8 form)."""
    rng = np.random.default_rng(4)
    frames = [dets((6.0 * t_of(k) + rng.normal(0.0, 0.2), 0.5 * t_of(k) ** 2, 0.1 * t_of(k), 6.0, t_of(k)))
              if k % 7 else NONE for k in range(60)]
    births, _, most = assert_same_as_filterpy(frames, [t_of(k) for k in range(len(frames))])
    assert births == 1 and most == 1


def test_time_must_not_go_back_without_a_reset():
    tracker = Tracker()
    tracker.step(1.0, dets((0.0, 0.0, 0.0, 0.0, 0.0)))
    with pytest.raises(ValueError, match="reset"):
        tracker.step(0.5, NONE)
    tracker.reset()
    assert list(tracker.step(0.5, dets((0.0, 0.0, 0.0, 0.0, 0.0)))["ids"]) == [1]
