"""Reactive traffic (core.traffic, `traffic.reactive`): agents keep their recorded paths and brake for the ego.

The ego follows a scripted plan (it brakes to a stop at a set deceleration, or drives on) so each case is the
interaction it names; the agents' recordings are constant-speed drives along a straight or a curved lane.
"""

import math

import numpy as np
import pytest
from traffic_scenes import CAR, REACTIVE, Braking, scene

from advperc_ros.core.geometry import Polyline
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.rollout import RolloutConfig, RolloutResult, judge, rollout
from advperc_ros.core.rules.base import evaluate
from advperc_ros.core.rules.contact import braked_too_hard, excusable
from advperc_ros.core.rules.forced_braking import ForcedBraking
from advperc_ros.core.rules.inputs import rule_inputs
from advperc_ros.core.tracker import Tracker
from advperc_ros.core.traffic import IDMParameters, RecordedPaths, agent_decelerations, deviations, simulate

# a quarter circle of 60 m radius, then straight on: a follower has to keep to a curve
ARC = [[60.0 * math.sin(a), 60.0 * (1.0 - math.cos(a))] for a in np.linspace(0.0, math.pi / 2, 90)]
CURVED = {"id": "bend", "centerline": [[-100.0, 0.0], *ARC, [60.0, 200.0]], "width": 3.5}


def drive(scenario, planner, config=REACTIVE):
    return rollout(scenario, PerceptionErrors.none(*scenario.agents.shape), Tracker(), planner, config)


def bumper_gap(result, scenario, slot):
    """(K,) m from the agent's front bumper to the ego's rear one, along x (the straight lane)."""
    agents = result.agents if result.agents is not None else scenario.agents
    frames = result.num_frames
    return (result.ego[:, 0] - agents.x[:frames, slot]) - CAR[0]


def test_a_follower_brakes_for_an_ego_that_stops_where_replay_drives_into_it():
    scenario = scene([{"id": 1, "start_s": 180.0, "speed": 12.0}])  # 20 m behind, as fast as the ego
    replayed = drive(scenario, Braking(3.0), RolloutConfig())
    assert replayed.collided  # the recording drives on into the stopped ego
    reacted = drive(scenario, Braking(3.0))
    assert not reacted.collided and reacted.num_frames == scenario.num_frames
    gap = bumper_gap(reacted, scenario, 0)
    assert gap.min() >= 0.9 * IDMParameters().min_gap  # it stops behind the ego, about IDM's least gap away
    speed = np.hypot(reacted.agents.vx[:, 0], reacted.agents.vy[:, 0])
    assert speed[-1] < 0.5 and speed[0] == pytest.approx(12.0)  # creeping up to IDM's least gap
    assert agent_decelerations(reacted.agents, scenario.agents, scenario.dt)[:, 0].max() <= IDMParameters().braking_max + 1e-9


def test_an_agent_ahead_of_the_ego_is_unchanged_to_the_bit():
    scenario = scene([{"id": 1, "start_s": 230.0, "speed": 6.0}, {"id": 2, "start_s": 150.0, "speed": 12.0}])
    reacted = drive(scenario, Braking(0.0))  # the ego drives on at 12 m/s behind agent 1, which goes at 6
    assert reacted.collided  # it runs into the slower agent ahead: that agent does not get out of its way
    for name in ("x", "y", "yaw", "vx", "vy"):
        assert np.array_equal(getattr(reacted.agents, name)[:, 0], getattr(scenario.agents, name)[:, 0])


def test_agents_the_ego_never_comes_near_replay_their_recording_to_the_bit():
    scenario = scene([{"id": 1, "start_s": 20.0, "speed": 12.0}, {"id": 2, "start_s": 0.0, "speed": 12.0}])
    reacted = drive(scenario, Braking(3.0))  # 180 m ahead of them, it stops; they are 8 s behind it
    assert reacted.agents.x[reacted.num_frames - 1, 0] < reacted.ego[-1, 0] - 60.0
    for name in ("x", "y", "yaw", "vx", "vy"):
        assert np.array_equal(getattr(reacted.agents, name), getattr(scenario.agents, name))
    assert deviations(scenario.agents, reacted.agents, scenario.dt) == ()


def test_a_chain_of_followers_brakes_one_behind_the_other():
    scenario = scene([{"id": 1, "start_s": 180.0, "speed": 12.0}, {"id": 2, "start_s": 160.0, "speed": 12.0}])
    reacted = drive(scenario, Braking(3.0))
    assert not reacted.collided
    first, second = reacted.agents.x[:, 0], reacted.agents.x[:, 1]
    assert np.all(first - second - CAR[0] > 0.5)  # the second keeps behind the first, which keeps behind the ego
    assert {d.agent for d in deviations(scenario.agents, reacted.agents, scenario.dt)} == {1, 2}


def test_a_reactive_rollout_is_deterministic_and_simulate_gives_its_agents_from_the_ego_alone():
    scenario = scene([{"id": 1, "start_s": 180.0, "speed": 12.0}, {"id": 2, "start_s": 160.0, "speed": 13.0}])
    first, again = drive(scenario, Braking(4.0)), drive(scenario, Braking(4.0))
    assert np.array_equal(first.ego, again.ego) and np.array_equal(first.distances, again.distances)
    rebuilt = simulate(RecordedPaths(scenario.agents), IDMParameters(), scenario.dt, (4.6, 1.9), first.ego)
    for name in ("x", "y", "yaw", "vx", "vy", "valid"):
        assert np.array_equal(getattr(rebuilt, name), getattr(first.agents, name))
    # a backend with only the ego's states (the graph's, a checkpoint's) is judged on the same agents
    judged = judge(RolloutResult(ego=first.ego, distances=first.distances), scenario, REACTIVE)
    assert np.array_equal(judged.agents.x, first.agents.x)


def test_recorded_paths_are_kept_to_the_centimetre_on_a_bend():
    lane = CURVED
    scenario = scene([{"id": 1, "start_s": 60.0, "speed": 12.0}], lane=lane, ego_s=85.0)
    centreline = Polyline(np.array(lane["centerline"]))
    reacted = drive(scenario, Braking(3.0, lane=centreline))
    assert not reacted.collided
    assert deviations(scenario.agents, reacted.agents, scenario.dt)  # it did brake for the ego
    recorded = Polyline(np.column_stack([scenario.agents.x[:, 0], scenario.agents.y[:, 0]]))
    _, off = recorded.project(np.column_stack([reacted.agents.x[:, 0], reacted.agents.y[:, 0]]))
    assert np.abs(off).max() < 0.01  # m: on its recorded path, between the positions it was recorded at


def test_an_agent_appears_and_leaves_when_its_recording_does():
    scenario = scene([{"id": 1, "start_s": 180.0, "speed": 12.0, "appear": 1.0, "disappear": 6.0}])
    reacted = drive(scenario, Braking(3.0))
    assert np.array_equal(reacted.agents.valid, scenario.agents.valid)


def test_forced_braking_is_the_hardest_braking_the_ego_forces_on_an_agent():
    scenario = scene([{"id": 1, "start_s": 185.0, "speed": 12.0}])  # 15 m behind: it must brake hard
    hard = drive(scenario, Braking(7.0))
    value = evaluate(ForcedBraking(), rule_inputs(hard, scenario, REACTIVE))
    forced = agent_decelerations(hard.agents, scenario.agents, scenario.dt)[: hard.num_frames, 0].max()
    assert forced > 4.05 and value.violated and value.value == pytest.approx(4.05 - forced)
    gentle = drive(scenario, Braking(1.5))
    assert not evaluate(ForcedBraking(), rule_inputs(gentle, scenario, REACTIVE)).violated
    replayed = drive(scenario, Braking(7.0), RolloutConfig())  # nobody answers the ego: +inf at every frame
    assert evaluate(ForcedBraking(), rule_inputs(replayed, scenario, RolloutConfig())).value == math.inf


def test_a_contact_from_behind_is_the_ego_s_fault_only_when_it_braked_harder_than_the_bound():
    dt, frames = 0.1, 40
    speeds = np.concatenate([np.full(10, 12.0), np.maximum(12.0 - 6.0 * dt * np.arange(1, 31), 0.0)])  # 6 m/s^2
    ego = np.column_stack([np.cumsum(speeds) * dt, np.zeros(frames), np.zeros(frames), speeds])
    scenario = scene([{"id": 1, "start_s": 180.0, "speed": 12.0}])
    behind = scenario.agents.select(slice(0, frames))
    behind.x[:] = ego[:, :1] - 4.0  # its centre behind the ego's rear bumper, touching it
    braked = braked_too_hard(speeds, dt)
    assert not braked[:9].any() and braked[15:35].all()
    replayed = excusable(ego, 4.6, behind)
    reactive = excusable(ego, 4.6, behind, reactive_dt=dt)
    assert replayed.all()  # replayed traffic: every contact from behind is excused
    assert np.array_equal(reactive[:, 0], ~braked)  # reactive: only where the ego did not brake too hard
    gentle = np.maximum(12.0 - 2.0 * dt * np.arange(frames), 0.0)
    assert not braked_too_hard(gentle, dt).any()


def test_the_batched_projection_is_polyline_project_to_the_bit():
    """RecordedPaths.project does every agent's Polyline.project (and Polyline.heading's segment) at once."""
    rng = np.random.default_rng(7)
    scenario = scene([{"id": 1, "start_s": 60.0, "speed": 12.0}, {"id": 2, "start_s": 10.0, "speed": 0.0},
                      {"id": 3, "start_s": 20.0, "speed": [[0.0, 6.0], [4.0, 15.0]]}], lane=CURVED, ego_s=85.0)
    paths = RecordedPaths(scenario.agents)
    assert paths.segments[1] == 0 and paths.segments[0] > 0 and paths.segments[2] > 0  # agent 2 is parked
    slots = rng.choice([0, 2], size=200)
    points = rng.uniform([-120.0, -20.0], [90.0, 220.0], size=(200, 2))
    stations, lateral, directions = paths.project(slots, points)
    for i, slot in enumerate(slots.tolist()):
        path = Polyline(np.column_stack([scenario.agents.x[:, slot], scenario.agents.y[:, slot]]))
        s, off = path.project(points[i : i + 1])
        assert (stations[i], lateral[i]) == (s[0], off[0])
        assert np.arctan2(directions[i, 1], directions[i, 0]) == path.heading(s[0])
