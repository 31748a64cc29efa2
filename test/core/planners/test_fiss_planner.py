"""fiss-planner's four Frenet planners through the plug-in interface (advperc_ros.contrib.fiss).

fiss-planner shares the main environment and the `test` extra installs it, so these tests run in CI's main
suite; they skip, saying so, only where the package is missing (a Python it has no wheel for).
"""

import json
import os

import numpy as np
import pytest
import yaml

from advperc_ros.cli import main
from advperc_ros.core.forks import WHOLE, Forks, PlannerSnapshots
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.planners.base import PlanningContext, planner_stats
from advperc_ros.core.planners.registry import load_planner
from advperc_ros.core.rollout import RolloutConfig, identical, rollout
from advperc_ros.core.scenario_spec import build_scenario
from advperc_ros.core.tracker import Tracker
from advperc_ros.exceptions import PluginError

fiss_planner = pytest.importorskip("fiss_planner", reason="fiss-planner is not installed (pip install '.[fiss]')")
from advperc_ros.contrib.fiss import VARIANTS, lanes_beside  # noqa: E402  (needs the package)

FISS = "advperc_ros.contrib.fiss:FissPlanner"
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
# the ego at 10 m/s, a car stopped in its lane 45 m ahead, the oncoming lane beside it free
STOPPED_AHEAD = {
    "name": "stopped_ahead",
    "dt": 0.1,
    "duration": 6.0,
    "lanes": [{"id": "east", "centerline": [[-50.0, -1.75], [300.0, -1.75]], "width": 3.5},
              {"id": "west", "centerline": [[300.0, 1.75], [-50.0, 1.75]], "width": 3.5}],
    "ego": {"route": ["east"], "start_s": 50.0, "speed": 10.0},
    "agents": [{"id": 1, "lane": "east", "start_s": 95.0, "speed": 0.0, "size": [4.6, 1.9, 1.6]}],
}
CONFIG = RolloutConfig(at_fault_only=True)


@pytest.fixture(scope="module")
def stopped_ahead():
    return build_scenario(STOPPED_AHEAD)


def _context(scenario) -> PlanningContext:
    return PlanningContext(route=scenario.route, lanes=scenario.lanes, dt=0.1, ego_length=4.6, ego_width=1.9)


def _rollout(scenario, planner, hide_the_car: bool):
    errors = PerceptionErrors.none(*scenario.agents.shape)
    errors.fn[:] = hide_the_car
    return rollout(scenario, errors, Tracker(), planner, CONFIG)


@pytest.mark.parametrize("variant", VARIANTS)
def test_each_variant_passes_a_car_it_sees_in_the_oncoming_lane_and_hits_it_hidden(stopped_ahead, variant):
    planner = load_planner(FISS, _context(stopped_ahead), {"variant": variant, "target_speed": 10.0})
    seen = _rollout(stopped_ahead, planner, hide_the_car=False)
    assert seen.inconclusive is None and not seen.collided and seen.num_frames == stopped_ahead.num_frames
    assert seen.ego[:, 1].max() > 1.0  # it overtook in the oncoming lane (centre y = 1.75)
    assert planner_stats(planner) is not None and len(planner_stats(planner).solve_times) == seen.num_frames

    hidden = _rollout(stopped_ahead, planner, hide_the_car=True)
    assert hidden.inconclusive is None and hidden.collided  # at fault: it drives into the car from behind
    assert np.abs(hidden.ego[:, 1] + 1.75).max() < 0.05  # in its lane all the way


def test_the_corridor_is_the_lanes_beside_the_route(stopped_ahead):
    """The oncoming lane is road to overtake on: one lane to the left, none to the right; with the params
    naming no lane to the left, the ego stops behind the car instead."""
    assert lanes_beside(_context(stopped_ahead), 3.5) == (1, 0)
    planner = load_planner(FISS, _context(stopped_ahead), {"target_speed": 10.0, "lanes_left": 0})
    kept = _rollout(stopped_ahead, planner, hide_the_car=False)
    assert not kept.collided and np.abs(kept.ego[:, 1] + 1.75).max() < 0.05
    assert kept.ego[-1, 3] < 3.0 and kept.min_signed_distance > 1.0  # slowed behind it, short of it


def test_its_own_fail_safes_count_as_planner_failures():
    """Both lanes blocked 12 m ahead of an ego at 10 m/s: the package brakes in an emergency, which the
    search log's planner failures (and the planner_failure rule) must see."""
    boxed = build_scenario({**STOPPED_AHEAD, "duration": 2.0, "agents": [
        {"id": 1, "lane": "east", "start_s": 62.0, "speed": 0.0, "size": [4.6, 1.9, 1.6]},
        {"id": 2, "lane": "west", "start_s": 288.0, "speed": 0.0, "size": [4.6, 1.9, 1.6]}]})
    planner = load_planner(FISS, _context(boxed), {"target_speed": 10.0})
    result = _rollout(boxed, planner, hide_the_car=False)
    assert result.inconclusive is None
    assert planner_stats(planner).failures > 0 and result.fallback_frames


def test_a_rollout_does_not_depend_on_the_rollouts_before_it(stopped_ahead):
    """The package keeps its previous plan (stitching, its fallback): reset() must clear it, or a replay or
    another worker would not see what the search saw."""
    fresh = _rollout(stopped_ahead, load_planner(FISS, _context(stopped_ahead), {"variant": "fiss"}), False)
    planner = load_planner(FISS, _context(stopped_ahead), {"variant": "fiss"})
    _rollout(stopped_ahead, planner, hide_the_car=True)
    assert identical(_rollout(stopped_ahead, planner, hide_the_car=False), fresh)


def test_it_is_rolled_out_whole_not_forked(stopped_ahead):
    """Its objects neither copy nor pickle, so no snapshot of it can be taken: every rollout runs from frame 0,
    with the same numbers as without the cache."""
    planner = load_planner(FISS, _context(stopped_ahead), {})
    assert PlannerSnapshots.of(planner).how == WHOLE
    forks = Forks(64 << 20, PlannerSnapshots.of(planner))
    errors = PerceptionErrors.none(*stopped_ahead.agents.shape).with_drop(0, 20, 40)
    full = rollout(stopped_ahead, errors, Tracker(), load_planner(FISS, _context(stopped_ahead), {}), CONFIG)
    for _ in range(2):
        assert identical(rollout(stopped_ahead, errors, Tracker(), planner, CONFIG, forks=forks), full)
    assert forks.forked == 0


def test_bad_parameters_are_refused_as_any_plug_in_does(stopped_ahead):
    with pytest.raises(PluginError, match="variant must be one of fop, fop_plus, fiss, fiss_plus"):
        load_planner(FISS, _context(stopped_ahead), {"variant": "fissplus"})
    with pytest.raises(PluginError, match="parameter 'variant' must be text"):
        load_planner(FISS, _context(stopped_ahead), {"variant": 3})
    with pytest.raises(PluginError, match="lanes_left"):
        load_planner(FISS, _context(stopped_ahead), {"lanes_left": -2})


def test_advperc_attack_attacks_fiss_planner_and_its_report_names_it(tmp_path):
    """A bundled scenario attacked with FISS+ through the command a user runs: a collision found by hiding the
    car it follows, and report.json naming the plug-in and its variant."""
    document = yaml.safe_load(open(os.path.join(REPO, "config", "idm_lane_following.yaml")))
    parameters = document["orchestrator"]["ros__parameters"]
    parameters.update(bag=os.path.join(REPO, "bags", "idm_lane_following"), planner=FISS,
                      planner_params={"variant": "fiss_plus", "target_speed": 14.0})
    parameters["search"]["budget"] = 40
    params = tmp_path / "fiss.yaml"
    params.write_text(yaml.safe_dump(document))
    assert main(["attack", str(params), "--output", str(tmp_path / "out")]) == 0
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["planner"] == FISS and report["params"]["planner_params"]["variant"] == "fiss_plus"
    assert report["collision"] is True and report["reproduced"] is True
