"""`attacked_layer`: the errors at the detector's output (the paper) or on the tracked objects the
planner reads (our tracker left out, for a team that brings only a planner)."""

from test_cli import write_params
from test_reproduced import _attack


def test_the_tracked_objects_as_the_attacked_layer_leave_our_tracker_out_and_say_so(repo, tmp_path):
    """`attacked_layer: tracks` (a team that brings only a planner): the planner reads the perturbed
    objects themselves, so a dropped agent is gone at once, with no track coasting on; the report says
    which layer was attacked."""
    from advperc_ros.backends.embedded import Stack
    from advperc_ros.configs import core_configs
    from advperc_ros.core.perception_errors import PerceptionErrors
    from advperc_ros.core.tracker import NoTracker, Tracker
    from advperc_ros.params import load_params
    from advperc_ros.ros.bag import read_scenario

    params = load_params(write_params(tmp_path / "p.yaml", repo, attacked_layer="tracks"))
    scenario = read_scenario(params.bag)
    stack = Stack(scenario, core_configs(params))
    paper = Stack(scenario, core_configs(params.with_values(attacked_layer="detections")))
    assert isinstance(stack.tracker, NoTracker) and isinstance(paper.tracker, Tracker)
    errors = PerceptionErrors.none(*scenario.agents.shape).with_drop(0, 20, 21)  # agent 0 missing at frame 20 only
    direct, tracked = stack.rollout(errors, record=True), paper.rollout(errors, record=True)
    lead = int(scenario.agents.ids[20, 0])
    assert lead not in direct.tracks[20]["ids"].tolist()  # gone from what the planner read
    assert len(tracked.tracks[20]["ids"]) == len(tracked.tracks[19]["ids"])  # the paper's tracker coasted it
    (tmp_path / "attack").mkdir()
    report, markdown = _attack(repo, tmp_path / "attack", attacked_layer="tracks")
    assert report["attacked_layer"] == "tracks" and report["params"]["attacked_layer"] == "tracks"
    assert "errors on the tracked objects" in markdown.splitlines()[0]
