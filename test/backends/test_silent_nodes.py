"""A frame that timed out names who should have answered it, and a report names the external nodes
it attacked in its config hash: the failures of issue 32 that named no node, and the three external
planners whose reports could not be told apart."""

from advperc_ros.backends.graph.rollouts import left_the_graph, silence_suspects, watch
from advperc_ros.params import load_params
from advperc_ros.ros.interfaces.registry import load_profile
from conftest import REPO


class SeenGraph:
    """A transport as the ROS graph API answers (rclpy's), made up: who publishes what, who is there."""

    def __init__(self, nodes: tuple[str, ...] | None, publishers: dict[str, tuple[str, ...]],
                 best_effort: dict[str, tuple[str, ...]] | None = None) -> None:
        self._nodes = nodes
        self._publishers = publishers
        self._best_effort = best_effort or {}

    def node_names(self):
        return self._nodes

    def publishers_of(self, topic):
        return None if self._nodes is None else self._publishers.get(topic, ())

    def best_effort_publishers(self, topic):
        return None if self._nodes is None else self._best_effort.get(topic, ())


def test_a_planner_that_never_started_is_named_by_the_topic_nobody_publishes():
    profile = load_profile("autoware")
    graph = SeenGraph(("/error_injector", "/orchestrator", "/scenario_player", "/tracker", "/rule_monitor"),
                      {profile.tracks.topic: ("/tracker",)})
    said = silence_suspects(graph, {"tracker": 11, "error_injector": 12, "scenario_player": 13, "rule_monitor": 14},
                            profile)
    assert said == (f"no node publishes plans on {profile.plan.topic}; "
                    f"tracked objects on {profile.tracks.topic} come from /tracker")


def test_a_node_that_announced_itself_and_died_is_named_gone():
    profile = load_profile("advperc")
    graph = SeenGraph(("/orchestrator", "/scenario_player", "/tracker"),
                      {profile.tracks.topic: ("/tracker",), profile.plan.topic: ("/my_planner",)})
    said = silence_suspects(graph, {"tracker": 1, "scenario_player": 2, "planner": 3}, profile)
    assert said.endswith("gone since they announced themselves on /attack/nodes: planner"), said
    assert f"plans on {profile.plan.topic} come from /my_planner" in said


def test_bare_dds_names_no_one_rather_than_blaming_nobody():
    """Bare DDS has no node names: no "no node publishes" (it cannot know), the processes say who died."""
    assert silence_suspects(SeenGraph(None, {}), {"planner": 3}, load_profile("advperc")) == ""


def test_a_running_node_that_left_the_graph_is_named_gone_and_only_what_was_seen_is_missed():
    """Issue 51: a team's planner gone mid-search had the search run on for 50 rollouts of a timeout each;
    leaving the ROS graph is how a node we did not start is seen gone (`graph.spawn_nodes: false`)."""
    profile = load_profile("autoware")
    up = SeenGraph(("/scenario_player", "/error_injector", "/my_planner", "/orchestrator"),
                   {profile.plan.topic: ("/my_planner",), profile.tracks.topic: ("/error_injector",)})
    # "planner_v2" is announced under a name no ROS node bears: never taken for gone
    present = {"scenario_player": 1, "error_injector": 2, "planner_v2": 3}
    watched = watch(up, present, profile)
    assert left_the_graph(up, watched, profile) is None
    without_planner = SeenGraph(("/scenario_player", "/error_injector", "/orchestrator"),
                                {profile.tracks.topic: ("/error_injector",)})
    assert left_the_graph(without_planner, watched, profile) == (
        f"/my_planner left the ROS graph: no node publishes plans on {profile.plan.topic} any more")
    without_player = SeenGraph(("/error_injector", "/my_planner"), {profile.plan.topic: ("/my_planner",),
                                                                     profile.tracks.topic: ("/error_injector",)})
    assert left_the_graph(without_player, watched, profile) == (
        "the node scenario_player left the ROS graph (announced on /attack/nodes, no longer in it)")


def test_bare_dds_never_sees_a_node_leave():
    """Bare DDS names no nodes: a team's node gone is seen as the timeouts of the frames it owed."""
    watched = watch(SeenGraph(None, {}), {"planner": 3}, load_profile("advperc"))
    assert left_the_graph(SeenGraph(None, {}), watched, load_profile("advperc")) is None


def test_a_best_effort_publisher_of_the_plans_is_named_by_its_qos():
    """Issue 51: a team's planner publishing best effort (our subscribers are reliable) ended "no plan stamped 0
    ... (a node is dead or silent)", rclpy's one warning lost mid-log."""
    profile = load_profile("autoware")
    graph = SeenGraph(("/my_planner", "/tracker"), {profile.plan.topic: ("/my_planner",),
                                                    profile.tracks.topic: ("/tracker",)},
                      {profile.plan.topic: ("/my_planner",)})
    said = silence_suspects(graph, {"tracker": 1}, profile)
    assert said.startswith(f"/my_planner publishes plans on {profile.plan.topic} best effort, which our reliable "
                           "subscribers never match: publish them reliable"), said


def test_three_external_planners_have_three_config_hashes_and_ours_keeps_its_own():
    params = load_params(REPO / "config" / "idm_lane_following.yaml")
    ours = params.config_hash()
    assert params.config_hash(planner_node=None, tracker_node=None) == ours  # a campaign's cells keep their hashes
    external = {params.config_hash(planner_node=node) for node in ("/a_planner", "/b_planner", "/c_planner")}
    assert len(external) == 3 and ours not in external
    assert params.config_hash(planner_node="/a_planner", tracker_node="/t") != params.config_hash(planner_node="/a_planner")


def test_a_team_s_node_may_announce_its_version_and_two_builds_are_two_configurations():
    import json

    import pytest

    from advperc_ros.exceptions import MessageError
    from advperc_ros.ros import messages as msgs
    from advperc_ros.ros.lockstep import parse_presence, presence_message

    assert parse_presence(presence_message("tracker", 42)) == ("tracker", 42, None)
    announced = msgs.string(json.dumps({"node": "my_planner", "pid": 7, "version": "v2.1-3-gabc"}))
    assert parse_presence(announced) == ("my_planner", 7, "v2.1-3-gabc")
    with pytest.raises(MessageError, match="'version' must be str"):
        parse_presence(msgs.string(json.dumps({"node": "my_planner", "pid": 7, "version": 2})))
    params = load_params(REPO / "config" / "idm_lane_following.yaml")
    builds = {params.config_hash(planner_node="/my_planner", planner_version=v) for v in ("v2.1", "v2.2", None)}
    assert len(builds) == 3
