"""The bundled scenarios: bags up to date, collision-free ground truth, robust to typical errors."""

from dataclasses import astuple

import numpy as np
import pytest

from advperc_ros.backends.embedded import Stack
from advperc_ros.configs import core_configs
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.metrics.nds import in_range
from advperc_ros.core.scenario_spec import load_scenario_spec
from advperc_ros.core.typical import TypicalErrorConfig, sample_typical_errors
from advperc_ros.params import load_params

# in-range object-frames of the paper's Table 1 (FN + TP), which the scenarios are sized after
PAPER_OBJECT_FRAMES = {"idm_lane_following": 465, "idm_overtake_follow": 682, "obp_overtake": 341, "obp_left_turn": 378,
                       "obp_right_turn": 817}
TYPICAL_SAMPLES = 100


def test_committed_bag_matches_its_description(bundled, repo):
    name, from_bag, _ = bundled
    described = load_scenario_spec(repo / "scenarios" / f"{name}.yaml")
    assert from_bag.name == described.name
    assert np.array_equal(from_bag.stamps_ns, described.stamps_ns)
    assert np.array_equal(from_bag.agents.valid, described.agents.valid)
    for field in ("x", "y", "yaw", "vx", "vy", "length", "width", "height"):
        a, b = getattr(from_bag.agents, field), getattr(described.agents, field)
        np.testing.assert_allclose(a[from_bag.agents.valid], b[described.agents.valid], atol=1e-9, err_msg=field)
    assert astuple(from_bag.ego_start) == pytest.approx(astuple(described.ego_start), abs=1e-12)
    np.testing.assert_allclose(from_bag.route.points, described.route.points)


def test_ground_truth_is_collision_free_and_sized_like_the_paper(bundled):
    name, scenario, params_path = bundled
    stack = Stack(scenario, core_configs(load_params(params_path)))
    result = stack.rollout(PerceptionErrors.none(*scenario.agents.shape))
    assert result.inconclusive is None
    assert result.num_frames == scenario.num_frames
    assert result.min_signed_distance > 0.3
    object_frames = int(in_range(scenario.agents, result.ego_xy).sum())
    assert 0.75 * PAPER_OBJECT_FRAMES[name] <= object_frames <= 1.25 * PAPER_OBJECT_FRAMES[name]


def test_typical_errors_cause_no_collision(idm_bundled):
    """The robustness stand-in: 100 rollouts with 0.2 m / 0.05 rad noise and 5 % single drops."""
    _, scenario, params_path = idm_bundled
    stack = Stack(scenario, core_configs(load_params(params_path)))
    rng = np.random.default_rng(12345)
    cfg = TypicalErrorConfig()
    worst = np.inf
    for _ in range(TYPICAL_SAMPLES):
        errors = sample_typical_errors(scenario.agents.shape, rng, cfg)
        result = stack.rollout(errors)
        assert result.inconclusive is None
        worst = min(worst, result.min_signed_distance)
    assert worst > 0.0


def test_typical_errors_have_the_stated_statistics():
    rng = np.random.default_rng(0)
    errors = sample_typical_errors((2000, 5), rng, TypicalErrorConfig())
    assert errors.dx.std() == pytest.approx(0.2, rel=0.05)
    assert errors.dyaw.std() == pytest.approx(0.05, rel=0.05)
    assert not np.any(errors.fn[1:] & errors.fn[:-1])
    assert 0.03 < errors.fn.mean() < 0.05


def test_pem_sampled_typical_errors_cause_no_collision(idm_bundled):
    """The paper's tuning criterion with the shipped PEM: 0 collisions in 100 samples."""
    from advperc_ros.core.pem import default_pem
    from advperc_ros.core.typical import check_typical

    _, scenario, params_path = idm_bundled
    stack = Stack(scenario, core_configs(load_params(params_path)))
    result = check_typical(scenario, stack.rollout, default_pem(), TYPICAL_SAMPLES, np.random.default_rng(0))
    assert result.passed, result
    assert result.min_signed_distance > 0.0
