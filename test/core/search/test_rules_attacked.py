"""Every rule of the rulebook attacked by the real search (`application.run_attack`, every error kind): for each
rule a stack whose ground truth keeps it, and a small search that finds perception errors that break it,
at a high NDS-t, judged in the report (`results.report.rulebook`, report.json's `rules`) as the search judged it.

The bundled IDM lane following is attacked where its IDM planner can be made to break the rule: by hiding or
displacing the lead (collision, time to collision) or showing a ghost it brakes for (phantom braking; with a
planner that may brake at 6 m/s², harder than the bundled 3.0, hard braking, comfort and a stop for nothing).
The IDM planner never leaves its route, so leaving the road, driving the wrong way and a planner's fallback are
attacked on small two-lane roads with a plug-in planner that swerves away from what it sees ahead
(`rule_planners.Evader`). A follower forced to brake hard needs traffic that reacts (`traffic.reactive`): a car
close behind the ego on a one-lane road, and an IDM that may brake at 6 m/s²."""

import math
from dataclasses import dataclass, field

import pytest
from conftest import REPO
from test_approach import LANE_Y, SPEED, SWERVE_SPEC

from advperc_ros.application import run_attack
from advperc_ros.core.rules.registry import RULES
from advperc_ros.core.scenario_spec import build_scenario
from advperc_ros.params import load_params
from advperc_ros.results.report import rulebook
from advperc_ros.ros.bag import read_scenario

BUDGET = 30  # rollouts: the heuristic's 12 and the phantom probes' 8 on the lane following, and a few rounds
HARD_BRAKER = {"target_speed": 14.0, "max_decel": 6.0}  # m/s²: beyond nuPlan's 4.05 hard-braking bound
EVADER = "rule_planners:Evader"

# The ego (at x = 0) drives east on a two-way road, a car 15 m behind it in its lane and one that has just
# passed it the other way (at x = -10): an Evader that swerves to the left drives into the oncoming lane to
# pass what it sees, and meets nobody there.
TWO_WAY_SPEC = {
    **SWERVE_SPEC,
    "name": "two_way",
    "lanes": [SWERVE_SPEC["lanes"][0], {"id": "west", "centerline": [[500.0, -LANE_Y], [-100.0, -LANE_Y]], "width": 3.5}],
    "agents": [
        {"id": 5, "lane": "east", "start_s": 85.0, "speed": SPEED, "size": [4.6, 1.9, 1.6]},  # behind
        {"id": 7, "lane": "west", "start_s": 510.0, "speed": SPEED, "size": [4.4, 1.8, 1.5]},  # passed, going away
    ],
}
# The ego at 12 m/s, a car 20 m behind it (centre to centre) at the same speed, and one far ahead: under reactive
# traffic the follower keeps its gap, until the ego brakes for a ghost harder than it can answer comfortably.
TAILGATED_SPEC = {
    "name": "tailgated", "dt": 0.1, "duration": 6.0,
    "lanes": [SWERVE_SPEC["lanes"][0]],
    "ego": {"route": ["east"], "start_s": 100.0, "speed": 12.0},
    "agents": [{"id": 5, "lane": "east", "start_s": 80.0, "speed": 12.0, "size": [4.6, 1.9, 1.6]},  # behind
               {"id": 9, "lane": "east", "start_s": 300.0, "speed": 12.0, "size": [4.6, 1.9, 1.6]}],  # far ahead
}


@dataclass(frozen=True)
class Case:
    """One rule attacked: on a bundled bag (`bag`) or a scenario description (`spec`), with a planner."""

    rule: str
    min_nds_t: float  # what the search reaches, a little below what it found when this test was written
    bag: str | None = "idm_lane_following"
    spec: dict | None = None
    planner: str = "idm"
    planner_params: dict = field(default_factory=lambda: {"target_speed": 14.0})
    reactive: bool = False  # traffic.reactive


CASES = (
    Case("collision", 0.8),  # the lead hidden, then shown displaced: the paper's attack
    Case("at_fault_collision", 0.8),
    Case("time_to_collision", 0.8),  # the lead hidden until the ego closes within 0.95 s of it
    Case("phantom_braking", 0.99),  # a ghost it brakes at its limit for
    Case("hard_braking", 0.99, planner_params=HARD_BRAKER),
    Case("comfort", 0.99, planner_params=HARD_BRAKER),
    Case("progress", 0.98, planner_params=HARD_BRAKER),  # a ghost at the start: it stops where the truth drives on
    # a ghost ahead: it swerves right, onto the shoulder beside the two lanes
    Case("drivable_area", 0.99, bag=None, spec=SWERVE_SPEC, planner=EVADER, planner_params={"offset": -3.5}),
    # a ghost ahead: it swerves left into the oncoming lane to pass it
    Case("driving_direction", 0.99, bag=None, spec=TWO_WAY_SPEC, planner=EVADER, planner_params={"offset": 3.5}),
    # a ghost ahead, and the car beside it where it would swerve to: boxed in, it falls back to braking
    Case("planner_failure", 0.99, bag=None, spec=SWERVE_SPEC, planner=EVADER, planner_params={"offset": 3.5}),
    # a ghost ahead: the ego brakes at 6 m/s², and the car behind it must brake harder than 4.05 m/s²
    Case("forced_braking", 0.98, bag=None, spec=TAILGATED_SPEC,
         planner_params={"target_speed": 12.0, "max_decel": 6.0}, reactive=True),
)


def attack(case: Case, planner: str | None = None):
    """The search on `case` with every error kind (`planner`: another planner in its place)."""
    scenario = read_scenario(REPO / "bags" / case.bag) if case.bag else build_scenario(case.spec)
    params = load_params(REPO / "config" / "idm_lane_following.yaml").with_values(**{
        "rule.name": case.rule, "errors.kinds": "all", "search.budget": BUDGET, "planner": planner or case.planner,
        "planner_params": {} if planner else case.planner_params, "traffic.reactive": case.reactive})
    return run_attack(scenario, params, progress=False)


def test_every_rule_of_the_rulebook_has_a_case():
    assert sorted(case.rule for case in CASES) == sorted(RULES)


@pytest.mark.parametrize("case", CASES, ids=[case.rule for case in CASES])
def test_the_search_breaks_the_rule_the_ground_truth_keeps(case):
    outcome = attack(case)
    judged = rulebook(outcome)
    truth, broken = judged["ground_truth_rules"][case.rule], judged["rules"][case.rule]
    assert not truth["violated"] and (truth["value"] is None or truth["value"] >= 0)  # None: +inf, no agent to meet
    assert broken["violated"] and broken["value"] < 0 and broken["frame"] is not None
    best = outcome.attack
    assert best.rollout.margin < 0 and math.isclose(best.rollout.margin, broken["value"], rel_tol=1e-6)
    assert best.scores.nds_t >= case.min_nds_t and outcome.reproduced
    assert len(outcome.log) <= BUDGET


@pytest.mark.parametrize("case", [case for case in CASES if case.planner == EVADER], ids=lambda case: case.rule)
def test_the_idm_planner_keeps_those_rules_whatever_it_is_shown(case):
    """Why those rules need the Evader: on the same road the IDM ego brakes for what it sees and stays on
    its route, and the same search finds nothing."""
    outcome = attack(case, planner="idm")
    assert outcome.best is None and not rulebook(outcome)["ground_truth_rules"][case.rule]["violated"]
