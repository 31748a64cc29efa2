"""The rule monitor's logic without ROS: every rule of the rulebook per frame on the drive so far, from the
same rule classes as the report, fed the embedded rollouts of idm_lane_following frame by frame as the
player and the graph publish them."""

import json

import numpy as np
import pytest
from conftest import REPO

from advperc_ros.backends.embedded import Stack
from advperc_ros.backends.graph.rollouts import GraphRollouts
from advperc_ros.backends.resumed import Checkpoint, ResumedRollouts
from advperc_ros.configs import core_configs
from advperc_ros.core.boxes import BOX_FIELDS
from advperc_ros.core.geometry import Polyline
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.rollout import RolloutResult
from advperc_ros.core.rules.base import evaluate
from advperc_ros.core.rules.inputs import rule_inputs
from advperc_ros.core.rules.registry import RULES, evaluate_rulebook, rule_class
from advperc_ros.core.scenario import EgoState
from advperc_ros.exceptions import MessageError
from advperc_ros.nodes.rule_monitor import RolloutSoFar, RuleMonitor, monitored_rules
from advperc_ros.params import load_params
from advperc_ros.ros import cdr
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.bag import read_scenario, read_topics
from advperc_ros.ros.lockstep import ReferenceDrive, parse_reference, parse_rule_diagnostics, reference_message
from advperc_ros.ros.topics import GROUND_TRUTH, LANES, ODOMETRY, REFERENCE, ROUTE, RULE_DIAGNOSTICS, RULE_TOPICS

BAG = REPO / "bags" / "idm_lane_following"
EVERY_RULE = tuple(RULE_TOPICS.values())
CAUSAL = ("collision", "at_fault_collision", "time_to_collision", "drivable_area", "driving_direction", "progress",
          "planner_failure", "forced_braking")
"""The rules whose value at a frame reads no later frame: on the drive so far, the report's value frame by frame."""
SMOOTHED = ("hard_braking", "comfort", "phantom_braking")
"""The motion rules, smoothed over frames on either side (Savitzky-Golay): equal to the report's at the last frame."""
TRUTH_FRAMES = 40  # of the ground truth's 251, fed where the test is about the start of a drive


class Recorder:
    """A transport that keeps what is published per topic, in order, and hands out the subscriptions'
    callbacks; `watched` topics have a subscriber."""

    def __init__(self, watched=EVERY_RULE) -> None:
        self.published: dict[str, list] = {}
        self.order: list[str] = []
        self.callbacks: dict[str, object] = {}
        self.watched = set(watched)

    def publisher(self, topic, msgtype, latched=False):
        sent = self.published.setdefault(topic, [])

        def publish(data):
            sent.append(data)
            self.order.append(topic)
        return type("Publisher", (), {"publish": staticmethod(publish),
                                      "matched_count": staticmethod(lambda: int(topic in self.watched))})()

    def subscriber(self, topic, msgtype, latched=False, callback=None, raw=False, wake=True):
        self.callbacks[topic] = callback

    @property
    def sent_on(self) -> set[str]:
        return {topic for topic, sent in self.published.items() if sent}

    def values(self, name: str, start: int = 0) -> np.ndarray:
        return np.array([msgs.TYPESTORE.deserialize_cdr(data, "std_msgs/msg/Float64").data
                         for data in self.published.get(RULE_TOPICS[name], [])[start:]])


class Said:
    def __init__(self) -> None:
        self.warnings: list[str] = []
        self.info = self.error = print

    def warning(self, message: str) -> None:
        self.warnings.append(message)


@pytest.fixture(scope="module")
def drives():
    """(scenario, rollout config, the ground truth's rollout, a rollout with the lead dropped: it hits it)."""
    scenario = read_scenario(BAG)
    configs = core_configs(load_params(REPO / "config" / "idm_lane_following.yaml"))
    stack = Stack(scenario, configs)
    truth = stack.rollout(PerceptionErrors.none(*scenario.agents.shape))
    attack = stack.rollout(PerceptionErrors.none(*scenario.agents.shape).with_drop(0, 20, scenario.num_frames - 1))
    assert attack.collided and attack.num_frames < truth.num_frames == scenario.num_frames
    return scenario, configs.rollout, truth, attack


DEFAULTS = load_params(REPO / "config" / "idm_lane_following.yaml").flat()


def test_the_monitor_judges_by_the_params_thresholds_as_the_search_and_the_report_do():
    """The node declares every `rule.<rule>.<parameter>` and builds its rules from the same Rulebook."""
    from advperc_ros.nodes.rule_monitor import SPEC
    from advperc_ros.params import RULE_THRESHOLDS

    assert set(RULE_THRESHOLDS) <= set(SPEC.params)
    rules = monitored_rules({**DEFAULTS, "rule.time_to_collision.least_min_ttc": 1.5})
    assert rules["time_to_collision"].parameters.least_min_ttc == 1.5
    assert monitored_rules(DEFAULTS)["time_to_collision"].parameters.least_min_ttc == 0.95


def monitor(drives, transport=None, road=True):
    config = drives[1]
    transport = transport or Recorder()
    said = Said()
    node = RuleMonitor(transport, config.ego_length, config.ego_width, said, monitored_rules(DEFAULTS))
    topics, _ = read_topics(BAG, [LANES, ROUTE], raw=True)
    for topic in (LANES, ROUTE) if road else ():
        transport.callbacks[topic](topics[topic][0][1])
    return node, transport, said


def feed(transport, scenario, result: RolloutResult, frames: int | None = None) -> None:
    """Frames 0..frames-1 of `result` as the player publishes them: the bag's own ground truth, the odometry."""
    messages = read_topics(BAG, [GROUND_TRUTH], raw=True)[0][GROUND_TRUTH]
    truth = {cdr.decode_objects(data, GROUND_TRUTH)[0]: data for _, data in messages}
    for k in range(result.num_frames if frames is None else frames):
        stamp = int(scenario.stamps_ns[k])
        transport.callbacks[GROUND_TRUTH](truth[stamp])
        transport.callbacks[ODOMETRY](msgs.ego_to_cdr(EgoState(*result.ego[k]), stamp))


def prefix(result: RolloutResult, frames: int) -> RolloutResult:
    return RolloutResult(ego=result.ego[:frames], distances=result.distances[:frames])


def test_every_rule_per_frame_is_the_rulebook_s_on_the_drive_so_far(drives):
    """Against the ground truth's rollout (/attack/reference): the rules that read no later frame are the report's
    values frame by frame, to the bit; the smoothed ones are each frame's value on the drive ending there, and the
    report's at the last frame (the report smooths the whole drive: its values are the reference)."""
    scenario, config, truth, attack = drives
    _, transport, _ = monitor(drives)
    transport.callbacks[REFERENCE](reference_message(ReferenceDrive(truth.ego, scenario.dt)))
    feed(transport, scenario, attack)
    reference = rule_inputs(truth, scenario, config)
    report = evaluate_rulebook(rule_inputs(attack, scenario, config), reference)
    for name in RULES:
        assert transport.values(name).size == attack.num_frames, name
    for name in CAUSAL:
        assert np.array_equal(transport.values(name), report[name].per_frame), name
    for name in SMOOTHED:
        live, whole = transport.values(name), report[name].per_frame
        assert live[-1] == whole[-1] and not np.array_equal(live, whole), name
        rule = rule_class(name)()
        so_far = [evaluate(rule, rule_inputs(prefix(attack, k + 1), scenario, config), reference).per_frame[-1]
                  for k in range(attack.num_frames)]
        assert np.array_equal(live, so_far), name
    assert report["collision"].violated and transport.values("collision").min() == report["collision"].value


def test_before_the_ground_truth_s_rollout_the_drive_is_judged_against_itself(drives):
    """As the report judges the ground truth's rollout; the first frame, before any frame period is known, too."""
    scenario, config, truth, _ = drives
    _, transport, _ = monitor(drives)
    feed(transport, scenario, truth, TRUTH_FRAMES)
    itself = rule_inputs(truth, scenario, config)
    report = evaluate_rulebook(itself, itself)
    for name in CAUSAL:
        assert np.array_equal(transport.values(name), report[name].per_frame[:TRUTH_FRAMES]), name
    for name in SMOOTHED:
        rule = rule_class(name)()
        so_far = [evaluate(rule, inputs := rule_inputs(prefix(truth, k + 1), scenario, config), inputs).per_frame[-1]
                  for k in range(TRUTH_FRAMES)]
        assert np.array_equal(transport.values(name), so_far), name
    assert np.all(transport.values("progress") == 1.0 - 0.2)


def test_the_player_s_diagnostics_come_first_and_as_before(drives):
    """The lockstep is untouched: each frame's /rules/diagnostics, the rollout's signed distances, goes out before
    any rule value, so the player never waits for the rules."""
    scenario, _, truth, _ = drives
    _, transport, _ = monitor(drives)
    feed(transport, scenario, truth, 5)
    per_frame = [RULE_DIAGNOSTICS] + [RULE_TOPICS[name] for name in RULES]
    assert transport.order == per_frame * 5
    for k, data in enumerate(transport.published[RULE_DIAGNOSTICS]):
        stamp, minimum, per_agent = parse_rule_diagnostics(data)
        assert stamp == scenario.stamps_ns[k] and minimum == truth.distances[k].min()
        slots = {int(agent): j for j, agent in enumerate(scenario.agents.ids.max(axis=0))}
        assert all(distance == truth.distances[k, slots[agent]] for agent, distance in per_agent.items())


def test_only_the_rules_someone_listens_to_are_evaluated(drives):
    """A search's graph has no subscriber on the rule topics: it pays for no rule."""
    scenario, _, truth, _ = drives
    _, quiet, _ = monitor(drives, Recorder(watched=()))
    feed(quiet, scenario, truth, 5)
    assert quiet.sent_on == {RULE_DIAGNOSTICS}
    _, one, _ = monitor(drives, Recorder(watched=(RULE_TOPICS["comfort"],)))
    feed(one, scenario, truth, 5)
    assert one.sent_on == {RULE_DIAGNOSTICS, RULE_TOPICS["comfort"]} and one.values("comfort").size == 5


def test_a_new_rollout_starts_the_drive_afresh(drives):
    scenario, _, truth, attack = drives
    reference = reference_message(ReferenceDrive(truth.ego, scenario.dt))
    _, fresh, _ = monitor(drives)
    fresh.callbacks[REFERENCE](reference)
    feed(fresh, scenario, attack)
    _, after, _ = monitor(drives)
    after.callbacks[REFERENCE](reference)
    feed(after, scenario, truth, TRUTH_FRAMES)
    feed(after, scenario, attack)
    for name in RULES:
        assert np.array_equal(after.values(name, TRUTH_FRAMES), fresh.values(name)), name


def test_without_the_route_no_rule_is_published_and_it_says_so_once(drives):
    scenario, _, truth, _ = drives
    _, transport, said = monitor(drives, road=False)
    feed(transport, scenario, truth, 3)
    assert transport.sent_on == {RULE_DIAGNOSTICS} and len(transport.published[RULE_DIAGNOSTICS]) == 3
    assert said.warnings == ["no /ego/route yet: the rules are not published until the player's route is in"]


def test_the_reference_round_trips_exactly_and_a_bad_one_is_named(drives):
    scenario, _, truth, _ = drives
    back = parse_reference(reference_message(ReferenceDrive(truth.ego, scenario.dt)))
    assert np.array_equal(back.ego, truth.ego) and back.dt == scenario.dt
    for data, says in (({"ego": [], "dt": 0.1}, "field 'ego' must be a non-empty Kx4 array"),
                       ({"ego": [[0.0, 0.0, 0.0]], "dt": 0.1}, "field 'ego' must be a 1x4 array of finite numbers"),
                       ({"ego": [[0.0, 0.0, 0.0, 1.0]], "dt": 0.0}, "field 'dt' must be a positive number"),
                       ({"ego": [[0.0, 0.0, 0.0, 1.0]]}, "field 'dt' must be float")):
        with pytest.raises(MessageError, match=f"^{REFERENCE}: {says}"):
            parse_reference(msgs.string(json.dumps(data)))


class Published:
    def __init__(self) -> None:
        self.sent: list = []
        self.reference = type("Publisher", (), {"publish": staticmethod(self.sent.append)})()


def test_the_graph_publishes_the_first_conclusive_rollout_on_perfect_perception_once(drives):
    scenario, _, truth, attack = drives
    graph = GraphRollouts.__new__(GraphRollouts)  # its processes are not what is tested here
    graph.scenario, graph._reference, graph._client = scenario, None, Published()
    perfect = PerceptionErrors.none(*scenario.agents.shape)
    graph.observe(perfect.with_drop(0, 20, scenario.num_frames - 1), attack)
    graph.observe(perfect, RolloutResult(ego=truth.ego[:3], distances=truth.distances[:3], inconclusive="a timeout"))
    assert graph._client.sent == []
    graph.observe(perfect.with_kind("ghost", 2), truth)  # every kind neutral is perfect perception too
    graph.observe(perfect, attack)
    (sent,) = graph._client.sent
    assert np.array_equal(parse_reference(sent).ego, truth.ego) and parse_reference(sent).dt == scenario.dt


def test_a_resumed_attack_shows_the_graph_the_ground_truth_it_answers_from_its_checkpoint(drives, tmp_path):
    scenario, config, _, _ = drives
    configs = core_configs(load_params(REPO / "config" / "idm_lane_following.yaml"))
    batch = [PerceptionErrors.none(*scenario.agents.shape),
             PerceptionErrors.none(*scenario.agents.shape).with_drop(0, 20, scenario.num_frames - 1)]
    ResumedRollouts(Stack(scenario, configs), Checkpoint(tmp_path / "out", "params", scenario, False),
                    scenario, config).rollout_many(batch)

    class Observed(Stack):
        def __init__(self, *args) -> None:
            super().__init__(*args)
            self.seen: list = []

        def observe(self, errors, result):
            self.seen.append((errors, result))

    backend = Observed(scenario, configs)
    resumed = ResumedRollouts(backend, Checkpoint(tmp_path / "out", "params", scenario, True), scenario, config)
    stored = resumed.rollout_many(batch)
    assert len(backend.seen) == 2
    assert all(errors is asked and result is answered
               for (errors, result), asked, answered in zip(backend.seen, batch, stored))


def test_the_drive_so_far_keeps_one_slot_per_agent_as_agents_come_and_go():
    """More frames and agents than its first room: every agent in a slot of its own over the frames, absent
    frames as a scenario leaves them (not valid, distance +inf), what was held kept through each growth."""
    so_far = RolloutSoFar()
    rng = np.random.default_rng(1)
    present = [np.sort(rng.choice(40, size=int(rng.integers(0, 30)), replace=False)) for _ in range(50)]
    for k, ids in enumerate(present):
        truth = {"ids": ids, **dict.fromkeys(BOX_FIELDS, ids + 0.5 * k)}
        so_far.add(k, truth, np.full(4, float(k)), -(ids + 0.25 * k))
    agents = so_far.agents()
    assert so_far.num_frames == 50 and agents.shape[1] == len(set(np.concatenate(present).tolist()))
    inputs = so_far.inputs(0.1, (), Polyline(np.array([[0.0, 0.0], [1.0, 0.0]])), (4.6, 1.9))
    for k, ids in enumerate(present):
        shown = agents.valid[k]
        assert sorted(agents.ids[k][shown].tolist()) == ids.tolist()
        order = np.argsort(agents.ids[k][shown])
        assert np.array_equal(agents.x[k][shown][order], ids + 0.5 * k)
        assert np.array_equal(inputs.distances[k][shown][order], -(ids + 0.25 * k))
        assert np.all(np.isinf(inputs.distances[k][~shown])) and np.array_equal(inputs.ego[k], np.full(4, float(k)))
    slot_ids = agents.ids[agents.valid.argmax(axis=0), np.arange(agents.shape[1])]  # each slot's id where first shown
    first = {int(agent): slot for slot, agent in enumerate(slot_ids)}
    assert all(agents.ids[k, first[int(agent)]] == agent for k, ids in enumerate(present) for agent in ids)


def test_under_reactive_traffic_the_monitor_judges_the_agents_as_they_drove_against_their_recording():
    """The player publishes the reacting agents; with the recording they left (`traffic.reactive`), the monitor's
    forced_braking and at-fault values are the report's, frame by frame: a follower made to brake hard shows live."""
    from traffic_scenes import REACTIVE, Braking, scene

    from advperc_ros.core.rollout import rollout
    from advperc_ros.core.tracker import Tracker

    scenario = scene([{"id": 1, "start_s": 185.0, "speed": 12.0}])  # 15 m behind an ego that brakes at 7 m/s^2
    drive = rollout(scenario, PerceptionErrors.none(*scenario.agents.shape), Tracker(), Braking(7.0), REACTIVE)
    transport = Recorder()
    RuleMonitor(transport, REACTIVE.ego_length, REACTIVE.ego_width, Said(), monitored_rules(DEFAULTS), scenario.agents)
    transport.callbacks[ROUTE](cdr.encode_path(scenario.route.points[:, 0], scenario.route.points[:, 1],
                                               scenario.route.heading(scenario.route.stations),
                                               [0] * len(scenario.route.points), 0))
    for k in range(drive.num_frames):
        stamp = int(scenario.stamps_ns[k])
        transport.callbacks[GROUND_TRUTH](cdr.encode_objects(drive.agents.frame(k), stamp, "ground_truth"))
        transport.callbacks[ODOMETRY](msgs.ego_to_cdr(EgoState(*drive.ego[k]), stamp))
    inputs = rule_inputs(drive, scenario, REACTIVE)
    report = evaluate_rulebook(inputs, inputs)
    assert report["forced_braking"].violated
    live = transport.values("forced_braking")
    np.testing.assert_allclose(live, report["forced_braking"].per_frame, rtol=0, atol=1e-9)
    assert live.min() < 0
