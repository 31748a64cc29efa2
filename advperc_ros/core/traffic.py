"""Traffic that reacts to the ego (`traffic.reactive`): recorded paths, speeds from IDM.

Replayed traffic, the default and the paper's, moves every agent as it was recorded whatever the ego
does. Reactive traffic keeps each agent's recorded path (the positions it was recorded at, and the
frames it appears and leaves) and simulates only its progress along that path, as nuPlan's IDM
agents follow their recorded paths:

- an agent on its recording replays it exactly while IDM toward its leader would not brake (the gap
  at least IDM's desired gap s*);
- otherwise it moves at IDM's speed: it brakes behind its leader, and once free heads back to its
  recording (the recording's speed plus its lag over `headway_time`, changing speed at most at
  `accel_max` and `decel_max`), never passing it: an agent is never ahead of where it was recorded.

Its leader is the nearest vehicle ahead on its path among the ego and the agents that have left their
recording. An agent that replays is not a leader: the recording already answers it (recorded
headways are often below IDM's desired 1.5 s, and IDM toward them would change traffic the ego never
touched), so an agent the ego never comes near replays its recording to the bit. Longitudinal only:
no agent changes lane or leaves its path. The frames of a rollout are a function of the recording
and the ego's states alone (`simulate`), so every backend moves the agents alike.
"""

import math
from dataclasses import dataclass, replace

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import Polyline, Polylines, wrap_angle
from advperc_ros.core.parameters import Bounds, parameter
from advperc_ros.core.scenario import EgoState

REPLAYED, REACTIVE = "replayed", "reactive"  # what a report says of its traffic
NUPLAN_IDM = "nuPlan idm_agents_observation.yaml"
DEVIATION = 0.01  # m: an agent this far from its recorded position has deviated (the report lists it)


@dataclass(frozen=True)
class IDMParameters:
    """The reactive agents' driver model: nuPlan's IDM agents' parameters, and how hard they may brake.

    nuPlan's `target_velocity` (10 m/s) has no counterpart: an agent's free motion is its recording.
    nuPlan clips an agent's deceleration at `decel_max`, so its agents cannot brake harder than 2 m/s^2
    and run into anything that does; here IDM's demand is followed up to a careful driver's full
    braking (`braking_max`), so a follower that had room stops and one that had not shows it."""

    min_gap: float = parameter(1.0, f"{NUPLAN_IDM}: min_gap_to_lead_agent (m)", Bounds(low=0.0, high=50.0))
    headway_time: float = parameter(1.5, f"{NUPLAN_IDM}: headway_time (s)", Bounds(low=0.0, high=10.0))
    accel_max: float = parameter(1.0, f"{NUPLAN_IDM}: accel_max (m/s^2)", Bounds(positive=True, high=10.0))
    decel_max: float = parameter(2.0, f"{NUPLAN_IDM}: decel_max, IDM's comfortable deceleration b (m/s^2)",
                                 Bounds(positive=True, high=15.0))
    braking_max: float = parameter(
        7.59, "UN Regulation No. 157 (ALKS), Annex 4 Appendix 3: the careful and competent driver's full "
              "braking, 0.774 g (m/s^2)", Bounds(positive=True, high=15.0))

    def desired_gap(self, speed: np.ndarray, closing: np.ndarray) -> np.ndarray:
        """IDM's desired gap s*(v, dv) (m) at `speed` closing on the leader at `closing` (v - v_lead); the
        dynamic part held at 0 or above as Treiber's IDM does (nuPlan's form lets a fast leader make it negative)."""
        dynamic = speed * self.headway_time + speed * closing / (2.0 * math.sqrt(self.accel_max * self.decel_max))
        return self.min_gap + np.maximum(dynamic, 0.0)

    def acceleration(self, speed: np.ndarray, closing: np.ndarray, gap: np.ndarray) -> np.ndarray:
        """IDM's acceleration with no desired speed of its own (the recording sets the free motion): accel_max
        on a free road, below 0 once the gap (clamped at `min_gap`, as nuPlan's) is under the desired one."""
        ratio = self.desired_gap(speed, closing) / np.maximum(gap, self.min_gap)
        return self.accel_max * (1.0 - ratio**2)


class RecordedPaths:
    """What reactive traffic reads of a scenario's recording, computed once per scenario: each agent's
    arc length along its recorded path at every frame (restarting where it appears), its recorded
    speed, and its path as a polyline (`geometry.Polyline`) for finding the leader on it, all of them held
    as `geometry.Polylines` so that a frame projects every leader onto every path in one numpy pass (a
    frame of a 44-car freeway recording had cost 28 projections one at a time)."""

    def __init__(self, agents: BoxSequence) -> None:
        self.agents = agents
        valid = agents.valid
        steps = np.hypot(np.diff(agents.x, axis=0), np.diff(agents.y, axis=0))
        arc = np.zeros(valid.shape)
        for k in range(1, valid.shape[0]):  # the arc restarts at each appearance
            arc[k] = np.where(valid[k - 1] & valid[k], arc[k - 1] + steps[k - 1], 0.0)
        self.arc = arc
        self.speed = np.hypot(agents.vx, agents.vy)
        paths: list[Polyline | None] = []
        for slot in range(valid.shape[1]):
            rows = valid[:, slot]
            try:
                paths.append(Polyline(np.column_stack([agents.x[rows, slot], agents.y[rows, slot]])))
            except ValueError:  # parked: it has no path to follow
                paths.append(None)
        self.lines = Polylines(paths)
        self.segments = self.lines.segments

    def project(self, slots: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(arc length, signed lateral offset, unit direction of the segment it falls on) of each point `xy` (P, 2)
        on the path of the agent in `slots` (P,): Polyline.project's, and its heading's segment, for each."""
        return self.lines.project(slots, xy)


_last_paths: list[RecordedPaths] = []  # the paths of the last recording asked for: a search asks for one


def recorded_paths(agents: BoxSequence) -> RecordedPaths:
    """The `RecordedPaths` of the recording `agents`, computed once for the rollouts of one scenario."""
    if not _last_paths or _last_paths[0].agents is not agents:
        _last_paths[:] = [RecordedPaths(agents)]
    return _last_paths[0]


class ReactiveTraffic:
    """The agents of one rollout under reactive traffic, a frame at a time: `agents` holds the frames
    so far (frames not reached yet hold the recording), `advance(k, ego)` writes frame k+1 from frame k
    and the ego's state at frame k. Deterministic in the recording, the parameters and the ego's states."""

    def __init__(self, paths: RecordedPaths, parameters: IDMParameters, dt: float, ego_size: tuple[float, float]) -> None:
        recorded = paths.agents
        self.paths, self.parameters, self.dt, self.ego_size = paths, parameters, dt, ego_size
        self.agents = replace(recorded, **{name: getattr(recorded, name).copy()
                                           for name in ("x", "y", "yaw", "vx", "vy")})
        self._progress = paths.arc[0].copy()  # m along each agent's path at the current frame
        self._speed = paths.speed[0].copy()  # m/s
        self._behind = np.zeros(recorded.shape[1], dtype=bool)  # behind its recording at the current frame
        self._start = np.zeros(recorded.shape[1], dtype=int)  # the frame its present appearance began

    def snapshot(self) -> tuple[np.ndarray, ...]:
        """The simulation's state at the current frame, beside the frames of `agents` written so far
        (which a restore takes from a rollout that reached this state: `restore`)."""
        return self._progress.copy(), self._speed.copy(), self._behind.copy(), self._start.copy()

    def restore(self, state: tuple[np.ndarray, ...], agents: BoxSequence, frames: int) -> None:
        """The simulation as `snapshot` took it once frames 0..frames-1 of `agents` were written."""
        self._progress, self._speed, self._behind, self._start = (array.copy() for array in state)
        for name in ("x", "y", "yaw", "vx", "vy"):
            getattr(self.agents, name)[:frames] = getattr(agents, name)[:frames]

    def advance(self, k: int, ego: EgoState) -> None:
        """Frame k+1 of the agents: each moves on from frame k as the module's docstring says."""
        paths, dt, nxt, p = self.paths, self.dt, k + 1, self.parameters
        valid = paths.agents.valid
        moving_on = valid[k] & valid[nxt]
        self._start[valid[nxt] & ~valid[k]] = nxt
        acceleration = self._idm_accelerations(k, ego, moving_on)
        recorded_speed = (paths.arc[nxt] - paths.arc[k]) / dt  # the recording's speed over this step
        landing_speed = (paths.arc[nxt] - self._progress) / dt  # the speed that lands on the recording
        braking = np.maximum(self._speed + np.maximum(acceleration, -p.braking_max) * dt, 0.0)  # IDM's
        # behind its recording: back to it over the headway time, at most at the comfortable rates
        lag = paths.arc[k] - self._progress
        catching_up = np.clip(recorded_speed + lag / max(p.headway_time, dt), self._speed - p.decel_max * dt,
                              self._speed + p.accel_max * dt)
        allowed = np.where(self._behind, np.minimum(catching_up, braking), braking)
        held_back = moving_on & (self._behind | (acceleration < 0.0)) & (allowed < landing_speed)
        progress, speed = paths.arc[nxt].copy(), paths.speed[nxt].copy()  # on its recording: its box's speed
        progress[held_back] = self._progress[held_back] + allowed[held_back] * dt
        speed[held_back] = allowed[held_back]
        self._progress, self._speed, self._behind = progress, speed, held_back
        for slot in np.flatnonzero(held_back).tolist():
            self._place(nxt, slot)

    def _place(self, frame: int, slot: int) -> None:
        """Agent `slot` at frame `frame` where its simulated progress puts it on its recorded path,
        between the two recorded frames around it, moving along its heading there at its simulated speed."""
        paths, agents = self.paths, self.agents
        arc = paths.arc[self._start[slot] : frame + 1, slot]
        s = self._progress[slot]
        before = min(int(np.searchsorted(arc, s, side="right")) - 1, arc.size - 2) + self._start[slot]
        span = paths.arc[before + 1, slot] - paths.arc[before, slot]
        share = (s - paths.arc[before, slot]) / span if span > 0.0 else 0.0
        recorded = paths.agents
        for name in ("x", "y"):
            values = getattr(recorded, name)[:, slot]
            getattr(agents, name)[frame, slot] = values[before] + share * (values[before + 1] - values[before])
        yaw = recorded.yaw[before, slot] + share * wrap_angle(recorded.yaw[before + 1, slot] - recorded.yaw[before, slot])
        agents.yaw[frame, slot] = wrap_angle(yaw)
        agents.vx[frame, slot] = self._speed[slot] * math.cos(yaw)
        agents.vy[frame, slot] = self._speed[slot] * math.sin(yaw)

    def _idm_accelerations(self, k: int, ego: EgoState, moving_on: np.ndarray) -> np.ndarray:
        """(N,) IDM's acceleration of each agent moving on from frame k toward its leader (module
        docstring), accel_max for one without a leader; a leader counts once its box is on the agent's
        path (its centre within both half widths of it) and ahead of the agent's centre."""
        parameters, agents = self.parameters, self.agents
        out = np.full(moving_on.shape, parameters.accel_max)
        ego_length, ego_width = self.ego_size
        leaders = [(ego.x, ego.y, ego.yaw, ego.v, ego_length, ego_width, -1)]
        for slot in np.flatnonzero(self._behind & moving_on).tolist():
            leaders.append((agents.x[k, slot], agents.y[k, slot], agents.yaw[k, slot], self._speed[slot],
                            agents.length[k, slot], agents.width[k, slot], slot))
        lead = np.array([row[:6] for row in leaders])  # (L, 6)
        # no leader farther than IDM's desired gap behind a stopped leader can make an agent brake
        reach = parameters.desired_gap(self._speed, self._speed) + agents.length[k] + lead[:, 4:5].max()
        near = np.hypot(agents.x[k][None, :] - lead[:, :1], agents.y[k][None, :] - lead[:, 1:2]) <= reach
        near[[i for i, row in enumerate(leaders) if row[6] >= 0], [row[6] for row in leaders if row[6] >= 0]] = False
        near[:, ~(moving_on & (self.paths.segments > 0))] = False  # no leader for the parked or the arriving
        leader_of, follower_of = np.nonzero(near)  # the pairs, leader-major
        if follower_of.size == 0:
            return out
        order = np.lexsort((leader_of, follower_of))  # follower-major, its leaders in their order (the ego first)
        leader_of, follower_of = leader_of[order], follower_of[order]
        followers = np.unique(follower_of)
        points = np.vstack([np.column_stack([agents.x[k, followers], agents.y[k, followers]]), lead[leader_of, :2]])
        stations, lateral, directions = self.paths.project(np.concatenate([followers, follower_of]), points)
        own = dict(zip(followers.tolist(), stations[: followers.size].tolist()))
        ahead = stations[followers.size:] - np.array([own[f] for f in follower_of.tolist()])
        width, length = agents.width[k, follower_of], agents.length[k, follower_of]
        on_path = (ahead > 0.0) & (np.abs(lateral[followers.size:]) < 0.5 * (width + lead[leader_of, 5]))
        gaps = np.where(on_path, ahead - 0.5 * (length + lead[leader_of, 4]), np.inf)
        firsts = np.flatnonzero(np.r_[True, follower_of[1:] != follower_of[:-1]])
        for first, last in zip(firsts.tolist(), [*firsts[1:].tolist(), follower_of.size]):
            nearest = first + int(np.argmin(gaps[first:last]))
            if not on_path[nearest]:
                continue
            slot, row = int(follower_of[nearest]), lead[leader_of[nearest]]
            direction = directions[followers.size + nearest]
            lead_speed = row[3] * math.cos(row[2] - float(np.arctan2(direction[1], direction[0])))
            speed = self._speed[slot]
            out[slot] = float(parameters.acceleration(np.asarray(speed), np.asarray(speed - lead_speed),
                                                      np.asarray(gaps[nearest])))
        return out


def simulate(paths: RecordedPaths, parameters: IDMParameters, dt: float, ego_size: tuple[float, float],
             ego: np.ndarray) -> BoxSequence:
    """The agents of a rollout whose ego states were `ego` (K, 4: x, y, yaw, v at frames 0..K-1): the same
    frames `ReactiveTraffic` wrote as the rollout ran, so a backend that has only the ego's states (the
    graph's, a checkpoint's) holds the truth its rollout was judged on. Frames from K on hold the recording."""
    traffic = ReactiveTraffic(paths, parameters, dt, ego_size)
    for k in range(min(ego.shape[0], paths.agents.shape[0]) - 1):
        traffic.advance(k, EgoState(*(float(value) for value in ego[k])))
    return traffic.agents


@dataclass(frozen=True)
class Deviation:
    """An agent that left its recording in a rollout: how far behind it fell and how hard it braked,
    so a reviewer sees who reacted to the ego and how much."""

    agent: int  # its id
    frames: int  # frames it was off its recording by more than DEVIATION
    max_distance: float  # m, the farthest it was from its recorded position
    hardest_braking: float  # m/s^2, its largest deceleration (0 when it never slowed)


def deviations(recorded: BoxSequence, simulated: BoxSequence, dt: float) -> tuple[Deviation, ...]:
    """The agents of `simulated` (frames 0..K-1 of a rollout) that left their recording, in slot order."""
    frames = simulated.shape[0]
    rec = recorded.frames(frames)
    off = np.where(rec.valid, np.hypot(simulated.x - rec.x, simulated.y - rec.y), 0.0)
    braking = agent_decelerations(simulated, rec, dt)
    out = []
    for slot in np.flatnonzero((off > DEVIATION).any(axis=0)).tolist():
        first = int(np.argmax(rec.valid[:, slot]))
        out.append(Deviation(int(rec.ids[first, slot]), int(np.count_nonzero(off[:, slot] > DEVIATION)),
                             float(off[:, slot].max()), float(max(braking[:, slot].max(initial=0.0), 0.0))))
    return tuple(out)


def agent_decelerations(agents: BoxSequence, recorded: BoxSequence, dt: float) -> np.ndarray:
    """(K, N) how hard each agent of `agents` brakes (m/s^2, > 0 braking) at frame k while it is off its recording
    `recorded` (the traffic model holds it back: frames where it replays, and the frame it lands back on its
    recording, read 0): the fall of its speed from frame k-1 to k, which off its recording is the model's own
    (IDM toward its leader, or heading back to its recording), so nothing of a recording's own noise (its box
    velocities, its positions' jitter) reads as a reaction. Causal: a rule monitor reads a frame's value on the
    drive so far."""
    out = np.zeros(agents.shape)
    if agents.shape[0] > 1:
        frames = agents.shape[0]
        rec = recorded.frames(frames)
        off = agents.valid & (np.hypot(agents.x - rec.x[:frames], agents.y - rec.y[:frames]) > 0.0)
        speed = np.hypot(agents.vx, agents.vy)
        out[1:] = np.where(off[1:] & agents.valid[:-1], (speed[:-1] - speed[1:]) / dt, 0.0)
    return out
