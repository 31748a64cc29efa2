"""The node graph: lockstep rollouts through separate OS processes over Cyclone DDS on loopback.

Every DDS test uses a domain id of its own in 100..199, from a block of ten that test_dds.py's
scheme (100 + (pid % 10) * 10) does not use in the same run, and localhost-only discovery.
Every wait is bounded (graph.timeout, the backend's startup timeout, thread joins).
"""

import contextlib
import csv
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("cyclonedds", reason="cyclonedds (PyPI) is not installed; the graph backend needs it")

from conftest import REPO, bare_dds_domains, need_ros  # noqa: E402

from advperc_ros.backends.embedded import Stack  # noqa: E402
from advperc_ros.configs import core_configs  # noqa: E402
from advperc_ros.cli import main as advperc  # noqa: E402
from advperc_ros.core.perception_errors import ERROR_KINDS, PerceptionErrors  # noqa: E402
from advperc_ros.core.planners.idm import IDMPlanner  # noqa: E402
from advperc_ros.backends.graph.rollouts import GraphRollouts  # noqa: E402
from advperc_ros.params import load_params, node_values  # noqa: E402
from advperc_ros.backends.resumed import checkpoint_folder  # noqa: E402
from advperc_ros.exceptions import MessageError, NodeGone, ParamsError  # noqa: E402
from advperc_ros.ros import lockstep  # noqa: E402
from advperc_ros.ros.topics import CONTROL_TYPE  # noqa: E402
from advperc_ros.ros.bag import read_scenario, write_ground_truth_bag  # noqa: E402
from advperc_ros.core.scenario_spec import build_scenario  # noqa: E402
from advperc_ros.core.traffic import deviations  # noqa: E402
from advperc_ros.ros.lockstep import RolloutClock  # noqa: E402

BAG = REPO / "bags" / "idm_lane_following"
TOLERANCE = 1e-9  # m, m/s, rad: graph against embedded (docs/graph.md)
ARM = "ADVPERC_TEST_HANG"  # env var naming the file that arms HangingPlanner
EXIT_AFTER = "ADVPERC_TEST_EXIT_AFTER"  # env var: plans after which ExitingPlanner's process exits, and where it says
_domain_ids = bare_dds_domains(50)  # test_dds starts 50 ids away


def next_domain_id() -> int:
    return next(_domain_ids)


class HangingPlanner(IDMPlanner):
    """The IDM planner, but once the file named by $ADVPERC_TEST_HANG exists it claims it (deletes
    it) at t >= 2 s and never answers again: a silent planner, or one to kill mid-rollout."""

    def plan(self, t, ego, tracks):
        arm = Path(os.environ[ARM])
        if t >= 2.0 and arm.exists():
            arm.unlink()
            while True:
                time.sleep(1.0)
        return super().plan(t, ego, tracks)


class ExitingPlanner(IDMPlanner):
    """The IDM planner, but with $ADVPERC_TEST_EXIT_AFTER set to "N:FILE" its process exits (code 3)
    at its N+1st plan, first writing into FILE how many rollouts it saw: a planner that crashes for good."""

    plans = 0
    rollouts_seen = -1  # IDMPlanner's constructor resets too

    def reset(self) -> None:
        ExitingPlanner.rollouts_seen += 1
        super().reset()

    def plan(self, t, ego, tracks):
        armed = os.environ.get(EXIT_AFTER)
        ExitingPlanner.plans += 1
        if armed is not None and ExitingPlanner.plans > int(armed.split(":", 1)[0]):
            Path(armed.split(":", 1)[1]).write_text(str(ExitingPlanner.rollouts_seen))
            os._exit(3)
        return super().plan(t, ego, tracks)


class UnreadyPlanner(IDMPlanner):
    """The IDM planner, but failing every plan of the first two rollouts its process sees: a node
    that answers before a latched input (an external planner's /ego/route) has reached it."""

    rollouts_seen = -1  # IDMPlanner's constructor resets too

    def reset(self) -> None:
        UnreadyPlanner.rollouts_seen += 1
        super().reset()

    def plan(self, t, ego, tracks):
        if UnreadyPlanner.rollouts_seen <= 2:
            raise RuntimeError("not ready")
        return super().plan(t, ego, tracks)


def params_for(tmp: Path, **overrides) -> Path:
    document = yaml.safe_load((REPO / "config" / "idm_lane_following.yaml").read_text())
    params = document["orchestrator"]["ros__parameters"]
    params["bag"] = str(BAG)
    params["search"]["random"].update(steps=2, proposals=20)
    params["search"]["refine"]["iterations"] = 1
    for dotted, value in {"dds.domain_id": next_domain_id(), "graph.timeout": 5.0, **overrides}.items():
        node = params
        *parents, leaf = dotted.split(".")
        for key in parents:
            node = node.setdefault(key, {})
        node[leaf] = value
    path = tmp / "params.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


@pytest.fixture(scope="module")
def scenario():
    return read_scenario(BAG)


def lead_drop(scenario) -> PerceptionErrors:
    """Errors dropping the lead vehicle (agent slot 0) from frame 20 on, plus small offsets: the
    IDM ego then collides with it."""
    errors = PerceptionErrors.none(*scenario.agents.shape).with_drop(0, 20, scenario.num_frames - 1)
    rng = np.random.default_rng(3)
    errors.dx[:] = rng.normal(0.0, 0.2, errors.dx.shape)
    errors.dy[:] = rng.normal(0.0, 0.2, errors.dy.shape)
    errors.dyaw[:] = rng.normal(0.0, 0.05, errors.dyaw.shape)
    return errors


def assert_same_rollout(graph, embedded) -> None:
    assert graph.num_frames == embedded.num_frames
    assert graph.inconclusive == embedded.inconclusive
    assert graph.collided == embedded.collided
    np.testing.assert_allclose(graph.ego, embedded.ego, rtol=0, atol=TOLERANCE)
    assert np.array_equal(np.isinf(graph.distances), np.isinf(embedded.distances))
    finite = np.isfinite(embedded.distances)
    np.testing.assert_allclose(graph.distances[finite], embedded.distances[finite], rtol=0, atol=TOLERANCE)


# ----- without DDS: the protocol's pieces ---------------------------------------------------------

def test_error_tensor_round_trips_exactly_through_json(scenario):
    errors = lead_drop(scenario)
    ids = scenario.agents.ids[0]
    back = lockstep.parse_errors(lockstep.errors_message(lockstep.RolloutErrors(7, errors, ids, scenario.stamps_ns, True)))
    assert back.rollout == 7 and back.errors.equals(errors) and back.ahead is True
    assert np.array_equal(back.agent_ids, ids) and np.array_equal(back.stamps_ns, scenario.stamps_ns)


def test_running_ahead_is_the_orchestrator_s_word_and_off_unless_said():
    """`ahead` travels from the errors to the ready message; a sender that does not say it means no."""
    import json as json_module

    for ahead in (True, False):
        assert lockstep.parse_ready(lockstep.ready_message(lockstep.RolloutReady(4, ahead))) == lockstep.RolloutReady(4, ahead)
    silent = lockstep.msgs.string(json_module.dumps({"rollout": 4}))
    assert lockstep.parse_ready(silent) == lockstep.RolloutReady(4, False)
    with pytest.raises(MessageError, match="'ahead' must be bool"):
        lockstep.parse_ready(lockstep.msgs.string(json_module.dumps({"rollout": 4, "ahead": 1})))


def test_a_stream_that_starts_again_drops_what_it_left_unpaired():
    """With the ground truth a frame ahead, a rollout that ended at frame k leaves tracks stamped
    t_{k+1} in flight; they may reach the planner after the next rollout's first odometry. The
    tracks stream's own restart (t_0 after t_{k+1}) drops them, so the next rollout's odometry of
    t_{k+1} pairs with that rollout's tracks, never with the stale ones."""
    answered = []
    pairs = lockstep.StampPairs(lambda stamp, tracks, ego: answered.append((stamp, tracks, ego)))
    for stamp in (0, 100):  # rollout 1: frames 0 and 1, then tracks of frame 2 ahead, unpaired at its end
        pairs.put(0, stamp, f"old tracks {stamp}")
        pairs.put(1, stamp, f"old ego {stamp}")
        pairs.clock.answer(stamp)
    pairs.put(0, 200, "old tracks 200")
    answered.clear()
    pairs.put(1, 0, "new ego 0")  # rollout 2 begins on the odometry stream
    pairs.put(0, 200, "old tracks 200")  # the stale tracks arrive late
    pairs.put(0, 0, "new tracks 0")  # the tracks stream starts again
    pairs.clock.answer(0)
    pairs.put(1, 100, "new ego 100")
    pairs.put(0, 100, "new tracks 100")
    pairs.clock.answer(100)
    pairs.put(1, 200, "new ego 200")  # before its tracks: it must wait for them
    assert [stamp for stamp, _, _ in answered] == [0, 100]
    pairs.put(0, 200, "new tracks 200")
    assert answered[-1] == (200, "new tracks 200", "new ego 200")


def test_rule_diagnostics_carry_every_agent_exactly():
    distances = np.array([0.1 + 0.2, -1e-300, np.inf])
    stamp, minimum, per_agent = lockstep.parse_rule_diagnostics(
        lockstep.rule_diagnostics(123_000_000_007, np.array([4, 9, 11]), distances))
    assert (stamp, minimum) == (123_000_000_007, -1e-300)
    assert per_agent == {4: 0.1 + 0.2, 9: -1e-300, 11: np.inf}


def test_rollout_clock_resets_on_a_stamp_not_after_the_last_answered():
    clock = RolloutClock()
    assert clock.observe(1_000) is False and clock.answer(1_000) == (True, 0.0)
    assert clock.observe(1_100) is False and clock.answer(1_100) == (False, 100 * 1e-9)
    assert clock.observe(1_000) is True  # the next rollout starts again at the first stamp
    assert clock.observe(1_000) is False  # its second input of that stamp is the same rollout
    assert clock.answer(1_000) == (True, 0.0)
    assert clock.observe(1_000) is True  # a rollout of one frame, then the next


def test_ground_truth_is_decoded_once_per_distinct_payload(scenario):
    from advperc_ros.nodes.runtime import ground_truth_objects
    from advperc_ros.ros import cdr

    data = cdr.encode_objects(scenario.agents.frame(3), int(scenario.stamps_ns[3]), "ground_truth")
    first, again = ground_truth_objects(data), ground_truth_objects(bytes(bytearray(data)))  # equal, not the same
    assert first[0] == again[0] == scenario.stamps_ns[3]
    assert first[1] is not again[1] and all(first[1][name] is again[1][name] for name in first[1])
    assert not first[1]["x"].flags.writeable  # shared arrays cannot be changed by one caller for all
    expected = cdr.decode_objects(data, "test")[1]
    assert all(np.array_equal(first[1][name], expected[name], equal_nan=True) for name in expected)


def test_each_node_gets_exactly_its_parameters(tmp_path):
    from advperc_ros.nodes.graph_nodes import SPECS, ros_parameters

    params = load_params(REPO / "config" / "idm_lane_following.yaml")
    by_node = {spec.name: ros_parameters(spec, params, BAG) for spec in SPECS}
    assert by_node["error_injector"] == {"graph.interface": "advperc"}
    assert by_node["tracker"] == {"tracker.gate": 2.0, "tracker.max_age": 1.0, "attacked_layer": "detections",
                                  "graph.interface": "advperc", "graph.drive": "messages", "graph.timeout": 10.0}
    assert by_node["scenario_player"] == {"bag": str(BAG), "stop_at_collision": True, "graph.timeout": 10.0,
                                          "graph.interface": "advperc", "graph.drive": "messages", "ego.length": 4.6,
                                          "ego.width": 1.9, "traffic.reactive": False, "traffic.min_gap": 1.0,
                                          "traffic.headway_time": 1.5, "traffic.accel_max": 1.0,
                                          "traffic.decel_max": 2.0, "traffic.braking_max": 7.59}
    assert by_node["planner"]["planner_params.target_speed"] == 14.0
    from advperc_ros.params import RULE_THRESHOLDS

    assert by_node["planner"]["planner"] == "idm" and by_node["rule_monitor"] == {
        "bag": str(BAG), "ego.length": 4.6, "ego.width": 1.9, "traffic.reactive": False,
        **{name: params.get(name) for name in RULE_THRESHOLDS}}
    for spec in SPECS:  # what the launch file hands a node is what the node accepts, unchanged
        values, planner_params = node_values(by_node[spec.name], spec.params, spec.name, spec.planner_params)
        assert values == {name: by_node[spec.name][name] for name in spec.params}
        assert planner_params == (params.planner_params if spec.planner_params else {})


def test_a_node_refuses_parameters_it_does_not_take():
    with pytest.raises(ParamsError, match="unknown parameter 'tracker.gate'.*takes: ego.length, ego.width"):
        node_values({"tracker.gate": 2.0}, ("ego.length", "ego.width"), "node 'rule_monitor'")
    with pytest.raises(ParamsError, match="unknown parameter 'planner_params.target_speed'"):
        node_values({"planner_params.target_speed": 2.0}, (), "node 'tracker'")
    with pytest.raises(ParamsError, match="'tracker.gate' must be a float"):
        node_values({"tracker.gate": 2}, ("tracker.gate",), "node 'tracker'")


def test_node_without_ros_refuses_a_bad_params_file(tmp_path, caplog):
    from advperc_ros.nodes.tracker import main

    assert main(["--params-file", str(params_for(tmp_path, **{"tracker.gate": 2}))]) == 2
    assert "tracker.gate" in caplog.text


def test_graph_parameters_are_validated(tmp_path):
    with pytest.raises(ParamsError, match="rollout_backend"):
        load_params(params_for(tmp_path, rollout_backend="dds"))
    with pytest.raises(ParamsError, match="dds.domain_id"):
        load_params(params_for(tmp_path, **{"dds.domain_id": 300}))
    with pytest.raises(ParamsError, match="graph.timeout"):
        load_params(params_for(tmp_path, **{"graph.timeout": 5}))
    params = load_params(params_for(tmp_path))
    assert "rollout_backend" not in params.canonical() and "dds.domain_id" not in params.canonical()
    assert params.config_hash() == params.with_values(rollout_backend="graph").config_hash()


# ----- (a) the nodes as separate processes give the embedded rollout ------------------------------

def test_graph_rollouts_with_the_obp_planner_equal_embedded_ones(tmp_path):
    """ObP in the planner node: CasADi/IPOPT in another process, warm starts and all, same rollout."""
    document = yaml.safe_load((REPO / "config" / "obp_overtake.yaml").read_text())
    document["orchestrator"]["ros__parameters"].update(bag=str(REPO / "bags" / "obp_overtake"),
                                                       dds={"domain_id": next_domain_id()})
    path = tmp_path / "obp.yaml"
    path.write_text(yaml.safe_dump(document))
    params = load_params(path)
    obp = read_scenario(REPO / "bags" / "obp_overtake")
    attack = PerceptionErrors.none(*obp.agents.shape).with_drop(0, 40, obp.num_frames - 1)
    with GraphRollouts(obp, core_configs(params), REPO / "bags" / "obp_overtake") as graph:
        assert_same_rollout(graph.rollout(attack), Stack(obp, core_configs(params)).rollout(attack))


def test_graph_rollouts_equal_embedded_ones(tmp_path, scenario):
    params = load_params(params_for(tmp_path))
    stack = Stack(scenario, core_configs(params))
    with GraphRollouts(scenario, core_configs(params), BAG) as graph:
        assert graph.perception_ahead  # our nodes, driven by messages: the ground truth runs a frame ahead
        assert sorted(graph.processes.running) == sorted(("scenario_player", "error_injector", "tracker", "planner", "rule_monitor"))
        assert len({p.pid for p in graph.processes.running.values()} | {os.getpid()}) == 6
        truth = PerceptionErrors.none(*scenario.agents.shape)
        result = graph.rollout(truth)
        assert_same_rollout(result, stack.rollout(truth))
        assert result.num_frames == scenario.num_frames and not result.collided
        attack = lead_drop(scenario)
        result = graph.rollout(attack, record=True)
        embedded = stack.rollout(attack, record=True)
        assert_same_rollout(result, embedded)
        assert result.collided and result.num_frames < scenario.num_frames
        assert len(result.tracks) == len(embedded.tracks) and len(result.plans) == len(embedded.plans)
        for got, want in zip(result.tracks, embedded.tracks):
            assert np.array_equal(got["ids"], want["ids"])
            np.testing.assert_allclose(got["x"], want["x"], rtol=0, atol=TOLERANCE)
        for got, want in zip(result.plans, embedded.plans):
            np.testing.assert_allclose(got.t, want.t, rtol=0, atol=TOLERANCE)
            np.testing.assert_allclose(np.stack([got.x, got.y]), np.stack([want.x, want.y]), rtol=0, atol=TOLERANCE)
        every_kind = _every_kind(attack, scenario)
        result = graph.rollout(every_kind, record=True)
        embedded = stack.rollout(every_kind, record=True)
        assert_same_rollout(result, embedded)  # the injector node keeps the history latency reads, ghosts travel
        assert any(len(got["ids"]) != len(want["ids"]) for got, want in zip(result.tracks, stack.rollout(attack, record=True).tracks))
        _check_live_rule_values(graph, stack, scenario, attack)
        processes = list(graph.processes.running.values())
    assert all(p.poll() is not None for p in processes)  # shut down on exit


def _check_live_rule_values(graph, stack, scenario, attack) -> None:
    """Watched, the rule monitor publishes every rule at every frame: the rulebook's value on the drive so far,
    judged against the ground truth's rollout, which the backend has latched on /attack/reference since the
    first rollout on perfect perception (docs/graph.md, "Rule values per frame")."""
    from advperc_ros.core.rollout import RolloutResult
    from advperc_ros.core.rules.base import evaluate
    from advperc_ros.core.rules.inputs import rule_inputs
    from advperc_ros.core.rules.registry import RULES, rule_class
    from advperc_ros.ros import messages as msgs
    from advperc_ros.ros.topics import RULE_TOPICS

    got: dict[str, list[float]] = {name: [] for name in RULES}
    transport = graph.client.transport
    readers = [transport.subscriber(RULE_TOPICS[name], "std_msgs/msg/Float64", raw=True, callback=lambda data, name=name:
                                    got[name].append(msgs.TYPESTORE.deserialize_cdr(data, "std_msgs/msg/Float64").data))
               for name in RULES]
    deadline = time.monotonic() + 30
    while not all(reader.matched_count() for reader in readers) and time.monotonic() < deadline:
        transport.spin_once(0.05)
    result = graph.rollout(attack)
    while any(len(values) < result.num_frames for values in got.values()) and time.monotonic() < deadline + 30:
        transport.spin_once(0.05)
    config = stack.config
    truth = rule_inputs(stack.rollout(PerceptionErrors.none(*scenario.agents.shape)), scenario, config)
    for name in RULES:
        rule = rule_class(name)()
        so_far = [evaluate(rule, rule_inputs(RolloutResult(ego=result.ego[: k + 1], distances=result.distances[: k + 1]),
                                              scenario, config), truth).per_frame[-1] for k in range(result.num_frames)]
        assert got[name] == so_far, name


def _every_kind(errors: PerceptionErrors, scenario) -> PerceptionErrors:
    """`errors` with an error of every extended kind on a few frames: late, turned, resized and wrongly fast
    cars, and a ghost beside the road for a second."""
    out = PerceptionErrors.none(*errors.shape, ERROR_KINDS, 2)
    for name in ("dx", "dy", "dyaw", "fn"):
        getattr(out, name)[:] = getattr(errors, name)
    out.latency[5:25, :] = 3
    out.flip[10:14, 1:] = True
    out.length_scale[:, 1:] = 1.4
    out.dvx[20:30, :] = -2.0
    out.ghost_on[8:18, 1] = True
    agents = scenario.agents
    out.ghost_x[8:18, 1], out.ghost_y[8:18, 1] = agents.x[8:18, 0] + 8.0, agents.y[8:18, 0] + 4.0
    return out


@pytest.mark.parametrize("interface, drive, layer", [("autoware", "clock", "detections"),
                                                     ("vision_msgs", "messages", "tracks")])
def test_graph_rollouts_through_a_stack_s_interface_equal_embedded_ones(tmp_path, scenario, interface, drive, layer):
    """Behind Autoware's types (DetectedObjects, PredictedObjects, Trajectory, Odometry on
    /localization/kinematic_state), driven by the clock, our tracker and planner give the embedded
    attack rollout within the graph's 1e-9, tracks and plans included; behind vision_msgs (detections
    without velocity) the embedded rollout with the same interface, whose detections carry no velocity
    either (and, with the tracked objects as the attacked layer, no tracker in between on either)."""
    params = load_params(params_for(tmp_path, **{"graph.interface": interface, "graph.drive": drive,
                                                 "attacked_layer": layer}))
    stack = Stack(scenario, core_configs(params))
    attack = lead_drop(scenario)
    with GraphRollouts(scenario, core_configs(params), BAG) as graph:
        assert graph.perception_ahead is (drive == "messages")  # a clock-driven planner gets each frame in turn
        assert graph.tracks_confirmed is (drive == "clock")  # our tracker says when every reader holds a frame
        result = graph.rollout(attack, record=True)
    embedded = stack.rollout(attack, record=True)
    assert_same_rollout(result, embedded)
    assert result.collided
    for got, want in zip(result.tracks, embedded.tracks):
        np.testing.assert_allclose(got["vx"], want["vx"], rtol=0, atol=TOLERANCE)
    for got, want in zip(result.plans, embedded.plans):
        np.testing.assert_allclose(got.t, want.t, rtol=0, atol=TOLERANCE)
    if interface == "vision_msgs":  # the interface changed what the planner saw: not the MarkerArray rollout
        markers = Stack(scenario, core_configs(params.with_values(**{"graph.interface": "advperc"}))).rollout(attack, record=True)
        assert any(not np.allclose(a["vx"], b["vx"]) for a, b in zip(markers.tracks, embedded.tracks) if len(a["vx"]) == len(b["vx"]))


FOLLOWED = {  # the ego behind a lead that stops, a car 16 m behind it: under reactive traffic it brakes for the ego
    "name": "followed", "dt": 0.1, "duration": 9.0,
    "lanes": [{"id": "east", "centerline": [[-200.0, -1.75], [600.0, -1.75]], "width": 3.5}],
    "ego": {"route": ["east"], "start_s": 200.0, "speed": 10.0},
    "agents": [{"id": 1, "lane": "east", "start_s": 225.0, "speed": [[0.0, 10.0], [2.0, 10.0], [5.0, 0.0]],
                "size": [4.6, 1.9, 1.6]},
               {"id": 2, "lane": "east", "start_s": 184.0, "speed": 10.0, "size": [4.6, 1.9, 1.6]}],
}


@pytest.mark.parametrize("drive", ["messages", "clock"])
def test_graph_rollouts_under_reactive_traffic_equal_embedded_ones(tmp_path, drive):
    """The player moves the agents (core.traffic) from the ego's odometry, frame by frame: the follower that
    brakes for the ego brakes alike in both, and the backend's agents are the ones the player published."""
    bag = tmp_path / "followed"
    write_ground_truth_bag(bag, build_scenario(FOLLOWED))
    scenario = read_scenario(bag)
    params = load_params(params_for(tmp_path, **{"bag": str(bag), "traffic.reactive": True, "graph.drive": drive}))
    configs = core_configs(params)
    truth = PerceptionErrors.none(*scenario.agents.shape)
    embedded = Stack(scenario, configs).rollout(truth, record=True)
    with GraphRollouts(scenario, configs, bag) as graph:
        result = graph.rollout(truth, record=True)
    assert_same_rollout(result, embedded)
    follower = deviations(scenario.agents, embedded.agents.frames(embedded.num_frames), scenario.dt)
    assert [d.agent for d in follower] == [2] and follower[0].hardest_braking > 1.0  # it reacted
    for name in ("x", "y", "vx", "vy"):
        np.testing.assert_allclose(getattr(result.agents, name)[embedded.agents.valid],
                                   getattr(embedded.agents, name)[embedded.agents.valid], rtol=0, atol=TOLERANCE)
    replayed = Stack(scenario, core_configs(params.with_values(**{"traffic.reactive": False}))).rollout(truth)
    assert replayed.collided and not embedded.collided  # replayed, the follower drives into the braking ego


# ----- (b) a search in graph mode writes the embedded report -----------------------------------------

def test_graph_search_writes_the_embedded_report(tmp_path, capsys):
    params = params_for(tmp_path)
    outputs = {backend: tmp_path / backend for backend in ("embedded", "graph")}
    for backend, output in outputs.items():
        assert advperc(["attack", str(params), "--output", str(output), "--quiet", "--backend", backend]) == 0
    reports = [json.loads((out / "report.json").read_text()) for out in outputs.values()]
    for report in reports:
        report.pop("wall_time_s")
    assert reports[0] == reports[1]
    assert reports[0]["collision"] is True and reports[0]["inconclusive_rollouts"] == 0
    logs = [list(csv.DictReader((out / "search_log.csv").open())) for out in outputs.values()]
    assert len(logs[0]) == len(logs[1]) == reports[0]["rollouts"]
    for embedded, graph in zip(*logs):  # the log writes distances to 10 digits: the last may differ
        assert float(embedded.pop("min_signed_distance")) == pytest.approx(float(graph.pop("min_signed_distance")), abs=TOLERANCE)
        assert embedded == graph


def test_graph_search_under_reactive_traffic_writes_the_embedded_report(tmp_path):
    """`advperc attack --reactive` on a drive where the car behind the ego brakes for it: the same report.json on
    both backends (its floats rounded, as the truth follows the ego's trajectory), saying who reacted."""
    bag = tmp_path / "followed"
    write_ground_truth_bag(bag, build_scenario(FOLLOWED))
    params = params_for(tmp_path, bag=str(bag))
    outputs = {backend: tmp_path / backend for backend in ("embedded", "graph")}
    for backend, output in outputs.items():
        assert advperc(["attack", str(params), "--output", str(output), "--quiet", "--backend", backend,
                        "--reactive"]) == 0
    reports = [json.loads((out / "report.json").read_text()) for out in outputs.values()]
    for report in reports:
        report.pop("wall_time_s")
    assert reports[0] == reports[1]
    assert reports[0]["traffic"] == "reactive" and reports[0]["collision"] and reports[0]["reproduced"]
    assert isinstance(reports[0]["deviated_agents"], list)
    markdown = (outputs["graph"] / "report.md").read_text()
    assert "Traffic reacts to the ego" in markdown
    from advperc_ros.ros.bag import read_objects  # noqa: PLC0415
    from advperc_ros.ros.topics import GROUND_TRUTH, RECORDED_AGENTS  # noqa: PLC0415

    attack_bag = outputs["embedded"] / "attack"
    _, recorded = read_objects(attack_bag, RECORDED_AGENTS)  # the recording beside the agents as they drove
    _, drove = read_objects(attack_bag, GROUND_TRUTH)
    original = read_scenario(bag).agents
    assert np.array_equal(recorded.x, original.x[: recorded.shape[0]]) and drove.shape == recorded.shape
    assert (not np.array_equal(drove.x, recorded.x)) == bool(reports[0]["deviated_agents"])
    layout = json.loads((outputs["embedded"] / "foxglove_layout.json").read_text())
    assert RECORDED_AGENTS in layout["configById"]["3D!attack"]["topics"]


def test_an_inconclusive_warm_up_is_sent_again_before_the_search_starts(tmp_path, scenario, monkeypatch):
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(Path(__file__).parent), str(REPO / "test"), os.environ.get("PYTHONPATH", "")]))
    params = load_params(params_for(tmp_path, planner="test_graph:UnreadyPlanner"))
    truth = PerceptionErrors.none(*scenario.agents.shape)
    expected = Stack(scenario, core_configs(params.with_values(planner="idm"))).rollout(truth)
    with GraphRollouts(scenario, core_configs(params), BAG) as graph:
        assert_same_rollout(graph.rollout(truth), expected)  # the first rollout after the warm-up


# ----- (c) a silent planner: that rollout is inconclusive, the next one proceeds; a dead one stops the search --

def test_a_silent_planner_makes_one_rollout_inconclusive_and_a_killed_one_stops_the_search(tmp_path, scenario,
                                                                                           monkeypatch, caplog):
    arm = tmp_path / "hang"
    monkeypatch.setenv(ARM, str(arm))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(Path(__file__).parent), str(REPO / "test"), os.environ.get("PYTHONPATH", "")]))
    params = load_params(params_for(tmp_path, planner="test_graph:HangingPlanner", **{"graph.timeout": 2.0}))
    truth = PerceptionErrors.none(*scenario.agents.shape)
    expected = Stack(scenario, core_configs(params.with_values(planner="idm"))).rollout(truth)
    caplog.set_level("ERROR", logger="advperc_ros.backends.graph")
    with GraphRollouts(scenario, core_configs(params), BAG) as graph:
        # silent: the planner stops answering; the player times out after graph.timeout, the nodes restart
        arm.touch()
        silent_planner = graph.processes.running["planner"].pid
        silent = graph.rollout(truth)
        assert "no plan stamped" in silent.inconclusive and "within 2 s" in silent.inconclusive
        assert graph.processes.running["planner"].pid != silent_planner  # restarted
        assert_same_rollout(graph.rollout(truth), expected)
        # killed mid-rollout: once the planner hangs at t >= 2 s, kill its process: gone for good
        arm.touch()
        planner = graph.processes.running["planner"]
        outcome = {}

        def run() -> None:
            try:
                outcome["result"] = graph.rollout(truth)
            except NodeGone as gone:
                outcome["gone"] = gone
        worker = threading.Thread(target=run)
        worker.start()
        try:
            deadline = time.monotonic() + 30.0
            while arm.exists() and time.monotonic() < deadline:
                time.sleep(0.01)
            assert not arm.exists(), "the planner never reached t = 2 s"
            os.kill(planner.pid, signal.SIGKILL)
        finally:
            worker.join(60.0)
        assert not worker.is_alive() and "result" not in outcome
        assert re.search(r"the search stops, as every rollout after would be inconclusive: in rollout \d+, the planner "
                         r"process was killed by signal SIGKILL", str(outcome["gone"]))
        with pytest.raises(NodeGone, match="planner process was killed"):  # known gone: not sent, not waited for
            graph.rollout(truth)
    lines = [r.getMessage() for r in caplog.records if r.levelname == "ERROR"]
    assert len(lines) == 1 and "inconclusive" in lines[0] and "restarting" in lines[0] and "no plan stamped" in lines[0]


def test_a_planner_that_exits_mid_search_stops_it_at_once_and_a_resume_finishes_it(tmp_path, monkeypatch, capsys):
    """Issue 51: a planner crashed for good had the search run on against it, some 50 rollouts of a timeout
    each. Now the rollout it dies in is the last: exit 4, one line naming it and its exit code, the
    checkpoint kept, and `--resume` with a healthy planner reruns from there to the whole report."""
    said = tmp_path / "rollouts_seen"
    frames = read_scenario(BAG).num_frames
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(Path(__file__).parent), str(REPO / "test"),
                                                      os.environ.get("PYTHONPATH", "")]))
    monkeypatch.setenv(EXIT_AFTER, f"{3 * frames}:{said}")  # the warm-up, the ground truth's and some of the search's
    params = params_for(tmp_path, planner="test_graph:ExitingPlanner")
    output = tmp_path / "out"
    started = time.monotonic()
    assert advperc(["attack", str(params), "--output", str(output), "--quiet", "--backend", "graph"]) == 4
    stopped = time.monotonic() - started
    lines = capsys.readouterr().err.strip().splitlines()
    assert "advperc: attacking our planner node (test_graph:ExitingPlanner)" in lines  # the graph names it, once up
    err = [line for line in lines if line.startswith("advperc: error:")]
    with capsys.disabled():  # seconds, not a timeout per rollout (timings are shown, never asserted)
        print(f"\nthe attack ended {stopped:.1f} s after it started, planner dead in its rollout {said.read_text()}")
    assert len(err) == 1 and "stops, as every rollout after would be inconclusive: in rollout" in err[0]
    assert "the planner process exited with code 3" in err[0], err
    assert f"--resume {output}" in err[0] and "warm-up" not in err[0]
    checkpointed = (checkpoint_folder(output) / "rollouts.jsonl").read_text().splitlines()
    seen = int(said.read_text())  # the rollouts the planner saw: the warm-up's, those checkpointed, the last
    assert 1 <= len(checkpointed) <= seen - 1  # at most the rollout it died in ran after its death
    assert not any(json.loads(line)["inconclusive"] for line in checkpointed)
    monkeypatch.delenv(EXIT_AFTER)
    assert advperc(["attack", str(params), "--resume", str(output), "--quiet", "--backend", "graph"]) == 0
    report = json.loads((output / "report.json").read_text())
    assert report["inconclusive_rollouts"] == 0 and report["rollouts"] > len(checkpointed)


# ----- (e) the rclpy path, where ROS 2 Jazzy is sourced -----------------------------------------------

def test_rclpy_transport_passes_rosbags_messages_through(ros_domain):
    rclpy = need_ros("rclpy")
    from rclpy.node import Node

    from advperc_ros.ros import messages as msgs
    from advperc_ros.ros.transport import RclpyTransport

    rclpy.init()
    try:
        sender, receiver = Node("advperc_test_sender"), Node("advperc_test_receiver")
        got = []
        RclpyTransport(receiver).subscriber("/advperc_test/done", CONTROL_TYPE, callback=got.append)
        publication = RclpyTransport(sender).publisher("/advperc_test/done", CONTROL_TYPE)
        transport = RclpyTransport(receiver)
        deadline = time.monotonic() + 10.0
        while publication.matched_count() < 1 and time.monotonic() < deadline:
            transport.spin_once(0.05)
        publication.publish(msgs.string("ünïcode"))
        while not got and time.monotonic() < deadline:
            transport.spin_once(0.05)
        assert [m.data for m in got] == ["ünïcode"]
        sender.destroy_node()  # its participant leaves the domain now, not whenever the worker collects garbage
        receiver.destroy_node()
    finally:
        rclpy.try_shutdown()


def test_rclpy_transport_sees_a_best_effort_publisher_by_its_qos(ros_domain):
    """The QoS check of issue 51 where rclpy shows it: a best-effort publisher is named, a reliable one not."""
    rclpy = need_ros("rclpy")
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    from advperc_ros.ros.transport import RclpyTransport

    rclpy.init()
    try:
        team, ours = Node("advperc_test_best_effort"), Node("advperc_test_watcher")
        team.create_publisher(String, "/advperc_test/plans", QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
        team.create_publisher(String, "/advperc_test/tracks", QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        transport = RclpyTransport(ours)
        deadline = time.monotonic() + 10.0
        while not transport.publishers_of("/advperc_test/tracks") and time.monotonic() < deadline:
            transport.spin_once(0.05)
        while not transport.best_effort_publishers("/advperc_test/plans") and time.monotonic() < deadline:
            transport.spin_once(0.05)
        assert transport.best_effort_publishers("/advperc_test/plans") == ("/advperc_test_best_effort",)
        assert transport.best_effort_publishers("/advperc_test/tracks") == ()
        team.destroy_node()
        ours.destroy_node()
    finally:
        rclpy.try_shutdown()


def test_node_executor_serves_everything_a_node_holds_to_a_team_s_typed_node(ros_domain):
    """NodeExecutor, which spins our nodes instead of rclpy.spin, against a typed node on rclpy's own
    executor: CDR bytes published raw arrive typed and typed messages arrive raw, a timer, a guard
    condition and the parameter services (`ros2 param`) are served, a QoS mismatch is reported,
    entities made after the first spin are served, a subscription that does not wake the spin is
    taken all the same, and a shutdown from elsewhere ends `spin`."""
    rclpy = need_ros("rclpy")
    from rcl_interfaces.srv import GetParameters
    from rclpy.event_handler import SubscriptionEventCallbacks
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    from advperc_ros.ros import messages as msgs
    from advperc_ros.ros.transport import RclpyTransport

    rclpy.init()
    try:
        ours, team = Node("advperc_test_ours"), Node("advperc_test_team")
        ours.declare_parameter("gate", 2.5)
        transport = RclpyTransport(ours)
        raw, typed, events, fired, quiet = [], [], [], [], []
        transport.subscriber("/advperc_test/in", CONTROL_TYPE, callback=raw.append, raw=True)
        transport.subscriber("/advperc_test/quiet", CONTROL_TYPE, callback=quiet.append, wake=False)
        out = transport.publisher("/advperc_test/out", CONTROL_TYPE)
        team.create_subscription(String, "/advperc_test/out", typed.append, 10)
        to_ours = team.create_publisher(String, "/advperc_test/in", 10)
        quietly = team.create_publisher(String, "/advperc_test/quiet", 10)
        ours.create_subscription(String, "/advperc_test/mismatch", lambda msg: None, 10, event_callbacks=
                                 SubscriptionEventCallbacks(incompatible_qos=events.append))
        team.create_publisher(String, "/advperc_test/mismatch", QoSProfile(depth=10,
                              reliability=ReliabilityPolicy.BEST_EFFORT))
        team_executor = SingleThreadedExecutor()
        team_executor.add_node(team)

        def spin_until(done) -> None:
            deadline = time.monotonic() + 10.0
            while not done() and time.monotonic() < deadline:
                transport.spin_once(0.02)
                team_executor.spin_once(0.02)
            assert done()

        spin_until(lambda: out.matched_count() and to_ours.get_subscription_count() and quietly.get_subscription_count()
                   and events)
        guard = ours.create_guard_condition(lambda: fired.append("guard"))  # made after the first spin
        timer = ours.create_timer(0.01, lambda: fired.append("timer"))
        guard.trigger()
        out.publish(msgs.string("to a typed node"))
        to_ours.publish(String(data="from a typed node"))
        quietly.publish(String(data="read without a wake-up"))
        client = team.create_client(GetParameters, "/advperc_test_ours/get_parameters")
        response = client.call_async(GetParameters.Request(names=["gate"]))
        spin_until(lambda: raw and typed and quiet and {"guard", "timer"} <= set(fired) and response.done())
        assert msgs.TYPESTORE.deserialize_cdr(raw[0], CONTROL_TYPE).data == "from a typed node"
        assert [m.data for m in typed] == ["to a typed node"] and [m.data for m in quiet] == ["read without a wake-up"]
        assert response.result().values[0].double_value == 2.5
        timer.cancel()  # nothing wakes the spin below but the shutdown

        def spin() -> None:
            with contextlib.suppress(ExternalShutdownException):
                transport.executor.spin()

        spinning = threading.Thread(target=spin, daemon=True)  # a hung spin fails the test, not the run
        spinning.start()
        time.sleep(0.2)
        rclpy.try_shutdown()
        spinning.join(timeout=10.0)
        assert not spinning.is_alive()
        team_executor.shutdown()
    finally:
        rclpy.try_shutdown()


@pytest.mark.parametrize("override, says", [
    ("tracker.gate:=-1.0", "'tracker.gate' must be positive"),
    ("tracker.gate:=2", "'tracker.gate' must be a float"),
    ("seed:=3", "unknown parameter 'seed'"),
    ("planner_params:={target_speed: 14.0}", "a ROS parameter cannot be a mapping"),
    ("tracker.gate:=[1", "parameter 'tracker.gate': cannot parse"),
])
def test_rclpy_node_main_refuses_a_bad_override_in_one_line(ros_domain, override, says):
    need_ros("rclpy")
    run = subprocess.run([sys.executable, "-m", "advperc_ros.nodes.tracker", "--ros-args", "-p", override],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and says in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1 and "Traceback" not in run.stderr


def test_example_external_planner_answers_every_tracks_message(ros_domain):
    need_ros("rclpy")
    import importlib.util

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from advperc_ros.core.scenario import EgoState
    from advperc_ros.ros import messages as msgs
    from advperc_ros.ros.bag import read_topics
    from advperc_ros.ros.topics import ODOMETRY, PLAN, ROUTE, TOPIC_TYPES, TRACKING
    from advperc_ros.ros.transport import RclpyTransport

    spec = importlib.util.spec_from_file_location("external_planner", REPO / "examples" / "external_planner.py")
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    rclpy.init()
    try:
        planner, tester = example.ExternalPlanner(), Node("advperc_test_graph")
        transport = RclpyTransport(tester)
        plans = []
        transport.subscriber(PLAN, TOPIC_TYPES[PLAN], callback=plans.append)
        publishers = {topic: transport.publisher(topic, TOPIC_TYPES[topic], latched=topic == ROUTE)
                      for topic in (ROUTE, TRACKING, ODOMETRY)}
        publishers[ROUTE].publish(read_topics(BAG, [ROUTE])[0][ROUTE][0][1])
        executor = SingleThreadedExecutor()
        executor.add_node(planner)
        executor.add_node(tester)
        deadline = time.monotonic() + 10.0
        while min(p.matched_count() for p in publishers.values()) < 1 and time.monotonic() < deadline:
            executor.spin_once(0.05)
        stamps = [1_000_000_000, 1_100_000_000, 1_000_000_000]  # the third starts a new rollout
        tracks = read_scenario(BAG).agents.frame(0)
        for count, stamp in enumerate(stamps, start=1):  # in lockstep, as the player drives it
            publishers[TRACKING].publish(msgs.objects_to_markers(tracks, stamp, "tracking"))
            publishers[ODOMETRY].publish(msgs.odometry(EgoState(0.0, -1.75, 0.0, 8.0), stamp))
            while len(plans) < count and time.monotonic() < deadline:
                executor.spin_once(0.05)
        assert [msgs.stamp_ns(p.header.stamp) for p in plans] == stamps
        _, pose_stamps = msgs.path_points(plans[0])
        assert pose_stamps[0] == stamps[0] and np.all(np.diff(pose_stamps) > 0)
        executor.shutdown()  # the nodes leave the domain now: a later test on this domain id would see them
        planner.destroy_node()
        tester.destroy_node()
    finally:
        rclpy.try_shutdown()


def test_launch_file_builds_the_graph():
    need_ros("launch_ros")
    import importlib.util

    from launch import LaunchContext

    spec = importlib.util.spec_from_file_location("attack_launch", REPO / "launch" / "attack.launch.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    started = []
    real_node = module.Node
    module.Node = lambda **kwargs: started.append(kwargs) or real_node(**kwargs)
    context = LaunchContext()
    for planner, tracker, nodes, interface, drive in (("ours", "ours", 6, "", ""),
                                                      ("external", "external", 4, "autoware", "clock")):
        started.clear()
        context.launch_configurations.update(params=str(REPO / "config" / "idm_lane_following.yaml"), planner=planner,
                                             tracker=tracker, output="", resume="false", interface=interface, drive=drive)
        module._graph(context)
        assert len(started) == nodes
        given = {node["name"]: {k: v for layer in node["parameters"] if isinstance(layer, dict) for k, v in layer.items()}
                 for node in started}
        for name in ("scenario_player", "error_injector", "orchestrator"):  # every one, alike
            assert given[name]["graph.interface"] == (interface or "advperc"), name
        assert given["scenario_player"]["graph.drive"] == given["orchestrator"]["graph.drive"] == (drive or "messages")


# ----- (f) graphs side by side, and what a killed one leaves ---------------------------------------------

def test_two_graph_searches_on_one_domain_give_their_solo_reports(tmp_path):
    """Each spawned graph talks in a DDS partition of its own, so the same params (same domain
    id) run twice at once give the report one run alone gives (a search of 8 rollouts: what is compared is
    the partitions, not the search)."""
    params = params_for(tmp_path, **{"search.budget": 8})
    solo = tmp_path / "solo"
    assert advperc(["attack", str(params), "--output", str(solo), "--quiet", "--backend", "embedded"]) == 0
    runs = [subprocess.Popen([sys.executable, "-m", "advperc_ros.cli", "attack", str(params), "--output",
                              str(tmp_path / f"graph{n}"), "--quiet", "--backend", "graph"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True) for n in range(2)]
    for run in runs:
        _, err = run.communicate(timeout=600)
        assert run.returncode == 0, err
    expected = json.loads((solo / "report.json").read_text())
    expected.pop("wall_time_s")
    for n in range(2):
        report = json.loads((tmp_path / f"graph{n}" / "report.json").read_text())
        report.pop("wall_time_s")
        assert report == expected


def test_a_killed_graph_s_log_folder_is_removed_by_the_next(tmp_path, monkeypatch):
    import tempfile

    from advperc_ros.backends.graph.processes import WORKDIR_PREFIX, remove_stale_workdirs

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    stale = tmp_path / f"{WORKDIR_PREFIX}{int(gone.stdout)}-abc"
    live = tmp_path / f"{WORKDIR_PREFIX}{os.getpid()}-def"
    stale.mkdir()
    live.mkdir()
    remove_stale_workdirs()
    assert not stale.exists() and live.exists()
