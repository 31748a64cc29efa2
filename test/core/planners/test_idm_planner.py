"""The IDM path-following planner (README, "System under attack") and the planner plug-in loader."""

import ast
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from advperc_ros.core.ego_motion import follow_plan
from advperc_ros.core.geometry import Polyline
from advperc_ros.core.planners.base import Planner, PlanningContext, Trajectory, planner_stats
from advperc_ros.core.planners.idm import IDMConfig, IDMPlanner
from advperc_ros.core.planners.registry import load_planner
from advperc_ros.core.scenario import EgoState
from advperc_ros.exceptions import PluginError

DT = 0.1
EGO_LENGTH, EGO_WIDTH = 4.6, 1.9
ROUTE = Polyline(np.array([[-100.0, 0.0], [3000.0, 0.0]]))  # straight, eastbound along y = 0
CONTEXT = PlanningContext(route=ROUTE, lanes=(), dt=DT, ego_length=EGO_LENGTH, ego_width=EGO_WIDTH)


def tracks(*boxes):
    """Tracks from (x, y, yaw, vx, length) tuples, width 1.9."""
    arr = np.array(boxes, dtype=float).reshape(-1, 5)
    n = arr.shape[0]
    return {
        "ids": np.arange(1, n + 1, dtype=np.int64),
        "x": arr[:, 0],
        "y": arr[:, 1],
        "yaw": arr[:, 2],
        "vx": arr[:, 3],
        "vy": np.zeros(n),
        "length": arr[:, 4],
        "width": np.full(n, 1.9),
        "height": np.full(n, 1.6),
    }


NO_TRACKS = tracks()


def plan_speeds(plan: Trajectory, v0: float) -> np.ndarray:
    """Speeds at the plan's poses, recovered from the travelled distances (trapezoidal steps) and v0."""
    s, _ = ROUTE.project(np.stack([plan.x, plan.y], axis=1))
    ds = np.diff(s)
    dt = np.diff(plan.t)
    v = [v0]
    for step, h in zip(ds, dt):
        v.append(2.0 * step / h - v[-1])
    return np.array(v)


def closed_loop(planner, ego, lead_x=None, lead_v=0.0, lead_length=4.6, frames=300):
    """Ego follows the plan frame by frame; an optional lead on the route moves at constant speed.
    Returns ego speeds, bumper gaps (nan without a lead) and ego states."""
    speeds, gaps, states = [], [], []
    for k in range(frames):
        t = k * DT
        trk = NO_TRACKS if lead_x is None else tracks((lead_x + lead_v * t, 0.0, 0.0, lead_v, lead_length))
        plan = planner.plan(t, ego, trk)
        ego = follow_plan(plan, t + DT)
        states.append(ego)
        speeds.append(ego.v)
        if lead_x is not None:
            gaps.append(lead_x + lead_v * (t + DT) - lead_length / 2 - (ego.x + EGO_LENGTH / 2))
        else:
            gaps.append(np.nan)
    return np.array(speeds), np.array(gaps), states


# ---------------------------------------------------------------- behaviour

def test_free_road_accelerates_to_target_and_never_exceeds_it():
    planner = IDMPlanner(CONTEXT, target_speed=10.0)
    speeds, _, states = closed_loop(planner, EgoState(0.0, 0.0, 0.0, 0.0), frames=600)
    assert np.all(speeds <= 10.0 + 1e-9)
    assert np.all(np.diff(speeds) >= -1e-9)  # monotone acceleration on a free road
    assert speeds[-1] == pytest.approx(10.0, abs=0.05)
    # it stays on the route
    assert max(abs(s.y) for s in states) < 1e-9
    assert max(abs(s.yaw) for s in states) < 1e-9


def test_free_road_plan_never_exceeds_target_speed_from_above_either():
    planner = IDMPlanner(CONTEXT, target_speed=10.0)
    plan = planner.plan(0.0, EgoState(0.0, 0.0, 0.0, 13.0), NO_TRACKS)
    v = plan_speeds(plan, 13.0)
    assert np.all(np.diff(v) <= 1e-9)  # above target it only slows down
    assert np.all(v >= 10.0 - 1e-6)


def test_initial_acceleration_from_rest_is_max_accel():
    planner = IDMPlanner(CONTEXT, target_speed=10.0)
    plan = planner.plan(0.0, EgoState(0.0, 0.0, 0.0, 0.0), NO_TRACKS)
    # a = a_max (1 - (v/v0)^4): at v = 0 the first step is a_max * dt
    assert plan_speeds(plan, 0.0)[1] == pytest.approx(1.0 * DT, rel=1e-9)


def test_follows_constant_speed_lead_at_equilibrium_gap():
    v0, v_lead = 10.0, 6.0
    planner = IDMPlanner(CONTEXT, target_speed=v0)
    speeds, gaps, _ = closed_loop(planner, EgoState(0.0, 0.0, 0.0, v_lead), lead_x=30.0, lead_v=v_lead, frames=500)
    # IDM equilibrium: s*(v, dv=0) = s0 + v T, and 1 - (v/v0)^delta - (s*/s)^2 = 0
    s_star = 1.0 + v_lead * 1.5
    s_eq = s_star / np.sqrt(1.0 - (v_lead / v0) ** 4)
    assert s_eq == pytest.approx(10.7187, abs=1e-4)
    assert gaps[-1] == pytest.approx(s_eq, abs=1e-3)
    assert speeds[-1] == pytest.approx(v_lead, abs=1e-3)
    assert np.all(gaps > 0.0)


def test_lead_gap_uses_lead_length():
    """The gap is bumper to bumper: a longer lead with the same centre is nearer."""
    planner = IDMPlanner(CONTEXT, target_speed=10.0)
    ego = EgoState(0.0, 0.0, 0.0, 8.0)
    s_ego = 100.0  # the route starts at x = -100
    short = planner.lead(s_ego, tracks((20.0, 0.0, 0.0, 5.0, 4.0)))
    long_ = planner.lead(s_ego, tracks((20.0, 0.0, 0.0, 5.0, 12.0)))
    assert short == pytest.approx((20.0 - 2.0 - 2.3, 5.0))
    assert long_ == pytest.approx((20.0 - 6.0 - 2.3, 5.0))
    # and the plan brakes harder for the longer one
    v_short = plan_speeds(planner.plan(0.0, ego, tracks((20.0, 0.0, 0.0, 5.0, 4.0))), 8.0)
    v_long = plan_speeds(planner.plan(0.0, ego, tracks((20.0, 0.0, 0.0, 5.0, 12.0))), 8.0)
    assert v_long[1] < v_short[1]


def test_stops_before_stationary_obstacle():
    planner = IDMPlanner(CONTEXT, target_speed=10.0)
    v_start, obstacle_x = 10.0, 45.0
    gap0 = obstacle_x - 2.3 - 2.3
    assert v_start**2 / (2 * 3.0) < gap0  # braking at max_decel suffices
    speeds, gaps, _ = closed_loop(planner, EgoState(0.0, 0.0, 0.0, v_start), lead_x=obstacle_x, lead_v=0.0, frames=300)
    assert np.all(gaps >= 0.0)
    assert speeds[-1] == pytest.approx(0.0, abs=1e-3)
    assert 0.0 <= gaps[-1] < 5.0  # it did drive up to the obstacle rather than stop miles away


def test_ignores_track_behind():
    planner = IDMPlanner(CONTEXT, target_speed=10.0)
    ego = EgoState(0.0, 0.0, 0.0, 5.0)
    free = planner.plan(0.0, ego, NO_TRACKS)
    behind = planner.plan(0.0, ego, tracks((-10.0, 0.0, 0.0, 0.0, 4.6)))
    np.testing.assert_array_equal(free.x, behind.x)


@pytest.mark.parametrize("seed", range(6))
def test_acceleration_within_bounds_along_plan(seed):
    rng = np.random.default_rng(seed)
    cfg = IDMConfig()
    planner = IDMPlanner(CONTEXT, target_speed=12.0)
    for _ in range(20):
        v = rng.uniform(0.0, 16.0)
        case = rng.integers(3)
        if case == 0:
            trk = NO_TRACKS
        elif case == 1:  # a lead anywhere from overlapping to far
            trk = tracks((rng.uniform(-1.0, 60.0), 0.0, 0.0, rng.uniform(0.0, 15.0), 4.6))
        else:  # a lead right on top of the ego (gap <= 0)
            trk = tracks((rng.uniform(0.5, 4.0), 0.0, 0.0, 0.0, 4.6))
        plan = planner.plan(0.0, EgoState(0.0, 0.0, 0.0, v), trk)
        speeds = plan_speeds(plan, v)
        accel = np.diff(speeds) / DT
        assert np.all(accel >= -cfg.max_decel - 1e-6)
        assert np.all(accel <= cfg.max_accel + 1e-6)
        assert np.all(speeds >= -1e-6)  # never reverses


def test_overlapping_lead_brakes_at_max_decel():
    planner = IDMPlanner(CONTEXT, target_speed=12.0)
    plan = planner.plan(0.0, EgoState(0.0, 0.0, 0.0, 10.0), tracks((3.0, 0.0, 0.0, 0.0, 4.6)))
    speeds = plan_speeds(plan, 10.0)
    assert speeds[1] == pytest.approx(10.0 - 3.0 * DT, abs=1e-9)


def test_adjacent_lane_ignored_but_intruding_track_counts():
    planner = IDMPlanner(CONTEXT, target_speed=10.0)
    ego = EgoState(0.0, 0.0, 0.0, 8.0)
    free = planner.plan(0.0, ego, NO_TRACKS)
    for lateral in (3.5, -3.5):
        beside = planner.plan(0.0, ego, tracks((25.0, lateral, 0.0, 0.0, 4.6)))
        np.testing.assert_array_equal(beside.x, free.x)
    for lateral in (1.5, -1.5):
        intruding = planner.plan(0.0, ego, tracks((25.0, lateral, 0.0, 0.0, 4.6)))
        assert intruding.x[-1] < free.x[-1] - 10.0  # it brakes for the stopped car
        assert intruding.x[-1] + 2.3 < 25.0 - 2.3  # and stays behind it


def test_rotated_track_reaching_into_corridor_counts():
    """A car 3.0 m to the side, turned 90 degrees (its 4.6 m length across the road), reaches into the corridor."""
    planner = IDMPlanner(CONTEXT, target_speed=10.0)
    ego = EgoState(0.0, 0.0, 0.0, 8.0)
    free = planner.plan(0.0, ego, NO_TRACKS)
    aligned = planner.plan(0.0, ego, tracks((20.0, 3.0, 0.0, 0.0, 4.6)))
    across = planner.plan(0.0, ego, tracks((20.0, 3.0, np.pi / 2, 0.0, 4.6)))
    np.testing.assert_array_equal(aligned.x, free.x)
    assert across.x[-1] < 20.0


def test_nearest_of_several_leads_is_used():
    planner = IDMPlanner(CONTEXT, target_speed=10.0)
    ego = EgoState(0.0, 0.0, 0.0, 8.0)
    both = planner.plan(0.0, ego, tracks((60.0, 0.0, 0.0, 8.0, 4.6), (20.0, 0.0, 0.0, 0.0, 4.6)))
    near_only = planner.plan(0.0, ego, tracks((20.0, 0.0, 0.0, 0.0, 4.6)))
    np.testing.assert_allclose(both.x, near_only.x)


def test_plan_covers_horizon_with_increasing_times():
    planner = IDMPlanner(CONTEXT, target_speed=10.0)
    plan = planner.plan(3.7, EgoState(5.0, 0.0, 0.0, 4.0), NO_TRACKS)
    assert plan.t[0] == pytest.approx(3.7)
    assert plan.t[-1] == pytest.approx(3.7 + 8.0)
    assert np.all(np.diff(plan.t) > 0)
    np.testing.assert_allclose(np.diff(plan.t), DT)
    assert len(plan.t) == len(plan.x) == len(plan.y) == len(plan.yaw) == 81
    assert plan.x[0] == pytest.approx(5.0)  # starts at the ego


def test_plan_follows_curved_route():
    route = Polyline(np.array([[0.0, 0.0], [50.0, 0.0], [50.0, 100.0]]))
    ctx = PlanningContext(route=route, lanes=(), dt=DT, ego_length=EGO_LENGTH, ego_width=EGO_WIDTH)
    plan = IDMPlanner(ctx, target_speed=10.0).plan(0.0, EgoState(40.0, 0.0, 0.0, 10.0), NO_TRACKS)
    s, lateral = route.project(np.stack([plan.x, plan.y], axis=1))
    np.testing.assert_allclose(lateral, 0.0, atol=1e-9)
    assert s[-1] > 60.0  # it went round the corner
    np.testing.assert_allclose(plan.yaw, route.heading(s))


def test_horizon_parameter():
    plan = IDMPlanner(CONTEXT, horizon=3.0).plan(0.0, EgoState(0.0, 0.0, 0.0, 4.0), NO_TRACKS)
    assert plan.t[-1] == pytest.approx(3.0)


def test_replan_period_holds_previous_plan_and_reset_clears_it():
    planner = IDMPlanner(CONTEXT, target_speed=10.0, replan_period=0.5)
    first = planner.plan(0.0, EgoState(0.0, 0.0, 0.0, 4.0), NO_TRACKS)
    assert planner.plan(0.2, EgoState(1.0, 0.0, 0.0, 4.0), NO_TRACKS) is first
    assert planner.plan(0.5, EgoState(2.0, 0.0, 0.0, 4.0), NO_TRACKS) is not first
    planner.reset()
    assert planner.plan(0.6, EgoState(3.0, 0.0, 0.0, 4.0), NO_TRACKS).t[0] == pytest.approx(0.6)


# ---------------------------------------------------------------- loading

IMPORTED_BY = """
import sys
import advperc_ros.core.planners.{module}
print(" ".join(sorted(m for m in ("advperc_ros.core.planners.idm", "advperc_ros.core.planners.obp", "casadi")
                      if m in sys.modules)))
"""


@pytest.mark.parametrize("module", ["base", "registry"])
def test_interface_and_registry_import_no_planner(module):
    """The interface and the registry import no implementation: no import circle, and IDM users
    never load CasADi. A fresh interpreter, since this one has imported everything."""
    out = subprocess.run([sys.executable, "-c", IMPORTED_BY.format(module=module)], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == ""


def test_interface_module_imports_nothing_of_the_planners_package():
    """base.py is imported by every planner, so it imports none of the package, not even inside a
    function (the old load_planner did, which closed an import circle)."""
    import advperc_ros.core.planners.base as base

    tree = ast.parse(Path(base.__file__).read_text())
    imported = [node.module if isinstance(node, ast.ImportFrom) else alias.name
                for node in ast.walk(tree) if isinstance(node, (ast.Import, ast.ImportFrom))
                for alias in node.names]
    assert not [name for name in imported if name.startswith("advperc_ros.core.planners")]


@pytest.mark.parametrize("module", ["idm", "obp"])
def test_each_planner_imports_on_its_own(module):
    """A planner module imported first, before anything else of the package, imports cleanly."""
    subprocess.run([sys.executable, "-c", f"import advperc_ros.core.planners.{module}"], check=True)


def test_load_bundled_idm_with_params():
    planner = load_planner("idm", CONTEXT, {"target_speed": 7.0})
    assert isinstance(planner, IDMPlanner)
    assert planner.config.target_speed == 7.0
    assert isinstance(planner, Planner)
    assert planner_stats(planner) is None  # it cannot fail: the search log leaves the column empty


@pytest.mark.parametrize("name", ["nosuch", "obp_typo"])
def test_load_unknown_planner_names_it(name):
    with pytest.raises(PluginError, match=name):
        load_planner(name, CONTEXT, {})


def test_load_missing_module_or_class(tmp_path, monkeypatch):
    with pytest.raises(PluginError, match="no_such_module_xyz:Thing"):
        load_planner("no_such_module_xyz:Thing", CONTEXT, {})
    (tmp_path / "empty_planner_mod.py").write_text("X = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(PluginError, match="empty_planner_mod:Missing"):
        load_planner("empty_planner_mod:Missing", CONTEXT, {})


@pytest.mark.parametrize("params, name", [
    ({"no_such_param": 1.0}, "no_such_param"),
    ({"target_speed": -1.0}, "target_speed"),
    ({"target_speed": "fast"}, "target_speed"),
    ({"max_decel": 0.0}, "max_decel"),
    ({"horizon": 0.0}, "horizon"),
    ({"horizon": float("inf")}, "horizon"),
    ({"headway": -0.5}, "headway"),
    ({"replan_period": -0.1}, "replan_period"),
    ({"min_gap": True}, "min_gap"),
])
def test_load_refuses_bad_params_in_one_line_naming_planner_and_parameter(params, name):
    with pytest.raises(PluginError) as refused:
        load_planner("idm", CONTEXT, params)
    message = str(refused.value)
    assert "'idm'" in message and f"'{name}'" in message and "\n" not in message


def test_out_of_range_is_a_value_error_of_the_planner_itself():
    with pytest.raises(ValueError, match="'target_speed'"):
        IDMPlanner(CONTEXT, target_speed=-1.0)
    with pytest.raises(ValueError, match="'exponent'"):
        IDMConfig(exponent=0.0)


def test_params_file_integers_are_floats():
    target_speed = load_planner("idm", CONTEXT, {"target_speed": 14}).config.target_speed
    assert target_speed == 14.0 and isinstance(target_speed, float)


PLUGIN_SOURCE = textwrap.dedent(
    """
    import numpy as np
    from advperc_ros.core.planners.base import Trajectory

    class CreepPlanner:
        def __init__(self, context, speed=1.0):
            self.context = context
            self.speed = speed
            self.resets = 0

        def reset(self):
            self.resets += 1

        def plan(self, t, ego, tracks):
            times = t + np.arange(11) * self.context.dt
            return Trajectory(t=times, x=ego.x + self.speed * (times - t), y=np.full(11, ego.y), yaw=np.zeros(11))

    class NotAPlanner:
        def __init__(self, context):
            pass
    """
)


def test_load_plugin_module_class(tmp_path, monkeypatch):
    (tmp_path / "creep_plugin_mod.py").write_text(PLUGIN_SOURCE)
    monkeypatch.syspath_prepend(str(tmp_path))
    planner = load_planner("creep_plugin_mod:CreepPlanner", CONTEXT, {"speed": 2.5})
    assert type(planner).__name__ == "CreepPlanner"
    assert planner.context is CONTEXT
    assert planner.speed == 2.5
    plan = planner.plan(1.0, EgoState(3.0, 0.0, 0.0, 0.0), NO_TRACKS)
    assert follow_plan(plan, 1.1).v == pytest.approx(2.5)
    assert planner_stats(planner) is None  # stats() is optional
    with pytest.raises(PluginError, match="creep_plugin_mod:NotAPlanner"):
        load_planner("creep_plugin_mod:NotAPlanner", CONTEXT, {})
    with pytest.raises(PluginError, match="creep_plugin_mod:CreepPlanner"):
        load_planner("creep_plugin_mod:CreepPlanner", CONTEXT, {"bogus": 1})
