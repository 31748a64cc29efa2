"""The perception error model: densities against scipy.stats, parameter recovery, sampling."""

import numpy as np
import pytest
from scipy import stats

from advperc_ros.core.pem import NUM_FEATURES, PEM, fit
from advperc_ros.core.pem.densities import _student_t_1d_logpdf, _student_t_2d_logpdf

TRUE = PEM(
    detection=(3.0, -2.0, -1.0, -2.5, 0.2),
    position_loc=(0.05, -0.02),
    radial_log_scale=(-1.6, 1.2, 0.0, 0.5, 0.0),
    tangential_log_scale=(-2.0, 0.8, 0.0, 0.3, 0.0),
    position_rho=0.3,
    position_nu=5.0,
    yaw_log_scale=(-3.0, 0.5, 0.0, 0.4, 0.0),
    yaw_nu=4.0,
    source="test",
)


def random_features(n: int, rng: np.random.Generator) -> np.ndarray:
    r = rng.uniform(0.0, 1.0, n)
    return np.stack([np.ones(n), r, r * r, rng.uniform(0.0, 1.0, n) ** 2, rng.uniform(0.6, 1.2, n)], axis=1)


def test_bivariate_t_density_equals_scipy():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(50, 2))
    loc, s1, s2, rho, nu = np.array([0.1, -0.2]), 0.7, 1.3, -0.4, 3.5
    shape = np.array([[s1 * s1, rho * s1 * s2], [rho * s1 * s2, s2 * s2]])
    reference = stats.multivariate_t(loc=loc, shape=shape, df=nu).logpdf(x)
    np.testing.assert_allclose(_student_t_2d_logpdf(x, loc, s1, s2, rho, nu), reference, rtol=1e-10)


def test_univariate_t_density_equals_scipy():
    x = np.linspace(-1, 1, 41)
    np.testing.assert_allclose(_student_t_1d_logpdf(x, 0.3, 4.0), stats.t(df=4.0, scale=0.3).logpdf(x), rtol=1e-10)


def test_fit_recovers_the_parameters_of_a_known_model():
    rng = np.random.default_rng(42)
    phi = random_features(40000, rng)
    detected, e, dyaw = TRUE.sample_features(phi, rng)
    got = fit(phi, detected, e, dyaw, "recovery test")
    # detection probabilities agree everywhere on the feature range
    check = random_features(2000, np.random.default_rng(1))
    assert np.abs(got.detection_probability(check) - TRUE.detection_probability(check)).max() < 0.03
    # scales agree within 5 %, correlation and location closely, degrees of freedom within 25 %
    for name in ("radial_log_scale", "tangential_log_scale", "yaw_log_scale"):
        ratio = np.exp(check @ (np.array(getattr(got, name)) - np.array(getattr(TRUE, name))))
        assert np.abs(ratio - 1.0).max() < 0.05, name
    assert got.position_rho == pytest.approx(TRUE.position_rho, abs=0.03)
    assert np.allclose(got.position_loc, TRUE.position_loc, atol=0.01)
    assert got.position_nu == pytest.approx(TRUE.position_nu, rel=0.25)
    assert got.yaw_nu == pytest.approx(TRUE.yaw_nu, rel=0.25)


def test_saved_model_loads_identically(tmp_path):
    TRUE.save(tmp_path / "pem.json")
    assert PEM.load(tmp_path / "pem.json") == TRUE
    assert len(TRUE.detection) == NUM_FEATURES


def test_samples_follow_the_model_marginals():
    """Kolmogorov-Smirnov of sampled errors against scipy.stats.t at fixed features."""
    phi = np.tile(np.array([1.0, 0.4, 0.16, 0.1, 0.9]), (20000, 1))
    detected, e, dyaw = TRUE.sample_features(phi, np.random.default_rng(3))
    assert detected.mean() == pytest.approx(TRUE.detection_probability(phi[:1])[0], abs=0.01)
    s1 = np.exp(phi[0] @ np.array(TRUE.radial_log_scale))
    s2 = np.exp(phi[0] @ np.array(TRUE.tangential_log_scale))
    sy = np.exp(phi[0] @ np.array(TRUE.yaw_log_scale))
    nu = TRUE.position_nu
    assert stats.kstest(e[:, 0], stats.t(df=nu, loc=TRUE.position_loc[0], scale=s1).cdf).pvalue > 0.01
    assert stats.kstest(e[:, 1], stats.t(df=nu, loc=TRUE.position_loc[1], scale=s2).cdf).pvalue > 0.01
    assert stats.kstest(dyaw, stats.t(df=TRUE.yaw_nu, scale=sy).cdf).pvalue > 0.01
    corr = np.corrcoef(e[np.all(np.abs(e) < 5 * max(s1, s2), axis=1)].T)[0, 1]
    assert corr == pytest.approx(TRUE.position_rho, abs=0.05)


def test_scenario_score_of_perfect_perception_equals_the_densities_at_zero():
    from toy_scenarios import FOLLOW_SPEC

    from advperc_ros.core.perception_errors import PerceptionErrors
    from advperc_ros.core.metrics.nds import in_range
    from advperc_ros.core.pem import default_pem, features
    from advperc_ros.core.scenario_spec import build_scenario

    scenario = build_scenario(FOLLOW_SPEC)
    truth = scenario.agents
    ego = np.stack([scenario.ego_start.x + 8.0 * scenario.times, np.full(scenario.num_frames, scenario.ego_start.y)], 1)
    counted = in_range(truth, ego)
    model = default_pem()
    phi = features(truth, ego)[counted]
    s1, s2 = np.exp(phi @ np.array(model.radial_log_scale)), np.exp(phi @ np.array(model.tangential_log_scale))
    sy = np.exp(phi @ np.array(model.yaw_log_scale))
    joint = [stats.multivariate_t(loc=[0, 0], shape=np.diag([a * a, b * b]), df=model.position_nu).logpdf([0, 0])
             for a, b in zip(s1, s2)]  # uncorrelated is not independent for a t: use the joint density
    expected = np.mean(
        np.log(model.detection_probability(phi)) + np.array(joint) + stats.t(df=model.yaw_nu, scale=sy).logpdf(0.0)
    )
    assert model.position_rho == 0.0 and model.position_loc == (0.0, 0.0)
    got = model.score(truth, PerceptionErrors.none(*truth.shape), ego, counted)
    assert got == pytest.approx(expected, rel=1e-12)


def test_pem_fit_from_bags_recovers_the_model_that_made_the_detections(tmp_path, repo):
    """Detections sampled from a known PEM into bags; `advperc pem fit` gets the model back."""
    from advperc_ros.backends.embedded import Stack
    from advperc_ros.configs import core_configs
    from advperc_ros.cli import main
    from advperc_ros.core.perception_errors import PerceptionErrors, inject
    from advperc_ros.core.scenario import EgoState
    from advperc_ros.params import load_params
    from advperc_ros.ros import messages as msgs
    from advperc_ros.ros import topics
    from advperc_ros.ros.bag import open_bag_for_writing, read_scenario

    rng = np.random.default_rng(11)
    paths = []
    for name in ("idm_lane_following", "idm_overtake_follow"):
        scenario = read_scenario(repo / "bags" / name)
        ego = Stack(scenario, core_configs(load_params(repo / "config" / f"{name}.yaml"))).rollout(
            PerceptionErrors.none(*scenario.agents.shape)).ego
        for copy in range(6):
            perceived = inject(scenario.agents, TRUE.sample(scenario.agents, ego[:, :2], rng))
            path = tmp_path / f"{name}_{copy}"
            with open_bag_for_writing(path) as bag:
                for k, ns in enumerate(scenario.stamps_ns):
                    ns = int(ns)
                    bag.write(topics.GROUND_TRUTH, ns, msgs.objects_to_markers(scenario.agents.frame(k), ns, "ground_truth"))
                    bag.write(topics.PERCEPTION, ns, msgs.objects_to_markers(perceived.frame(k), ns, "perception"))
                    bag.write(topics.ODOMETRY, ns, msgs.odometry(EgoState(*ego[k]), ns))
            paths.append(str(path))
    output = tmp_path / "fitted.json"
    assert main(["pem", "fit", *paths, "--output", str(output)]) == 0
    got = PEM.load(output)
    assert "fitted by advperc pem fit" in got.source
    # the bundled scenes span little of the feature space: compare where they are (near range, open view)
    near = np.array([[1.0, r, r * r, 0.0, 0.87] for r in np.linspace(0.05, 0.6, 12)])
    assert np.abs(got.detection_probability(near) - TRUE.detection_probability(near)).max() < 0.05
    ratio = np.exp(near @ (np.array(got.radial_log_scale) - np.array(TRUE.radial_log_scale)))
    assert np.abs(ratio - 1.0).max() < 0.25


def test_pem_fit_from_nuscenes_detection_results(tmp_path, repo):
    """Detections of a known PEM written in the devkit's JSON formats; the fit recovers the PEM."""
    import json

    from advperc_ros.backends.embedded import Stack
    from advperc_ros.configs import core_configs
    from advperc_ros.cli import main
    from advperc_ros.core.perception_errors import PerceptionErrors, inject
    from advperc_ros.params import load_params
    from advperc_ros.ros.bag import read_scenario

    def box(token, x, y, yaw, length, width, height, ego_xy=None, score=None):
        out = {"sample_token": token, "translation": [x, y, 0.8], "size": [width, length, height],
               "rotation": [float(np.cos(yaw / 2)), 0.0, 0.0, float(np.sin(yaw / 2))], "velocity": [0.0, 0.0],
               "detection_name": "car", "attribute_name": "vehicle.moving"}
        if ego_xy is not None:
            out.update(ego_translation=[x - ego_xy[0], y - ego_xy[1], 0.8], num_pts=10, detection_score=-1.0)
        if score is not None:
            out["detection_score"] = score
        return out

    rng = np.random.default_rng(5)
    gt, results = {}, {}
    for name in ("idm_lane_following", "idm_overtake_follow"):
        scenario = read_scenario(repo / "bags" / name)
        ego = Stack(scenario, core_configs(load_params(repo / "config" / f"{name}.yaml"))).rollout(
            PerceptionErrors.none(*scenario.agents.shape)).ego_xy
        for copy in range(6):
            seen = inject(scenario.agents, TRUE.sample(scenario.agents, ego, rng))
            for k in range(scenario.num_frames):
                token = f"{name}-{copy}-{k}"
                t, p = scenario.agents.frame(k), seen.frame(k)
                gt[token] = [box(token, *(float(t[f][i]) for f in ("x", "y", "yaw", "length", "width", "height")),
                                 ego_xy=ego[k]) for i in range(len(t["x"]))]
                results[token] = [box(token, *(float(p[f][i]) for f in ("x", "y", "yaw", "length", "width", "height")),
                                      score=float(p["score"][i])) for i in range(len(p["x"]))]
    (tmp_path / "gt.json").write_text(json.dumps({"results": gt}))
    (tmp_path / "results.json").write_text(json.dumps({"meta": {"use_lidar": True}, "results": results}))
    output = tmp_path / "fitted.json"
    assert main(["pem", "fit", str(tmp_path / "results.json"), "--nuscenes-gt", str(tmp_path / "gt.json"),
                 "--output", str(output)]) == 0
    got = PEM.load(output)
    near = np.array([[1.0, r, r * r, 0.0, 0.87] for r in np.linspace(0.05, 0.6, 12)])
    assert np.abs(got.detection_probability(near) - TRUE.detection_probability(near)).max() < 0.05
    ratio = np.exp(near @ (np.array(got.radial_log_scale) - np.array(TRUE.radial_log_scale)))
    assert np.abs(ratio - 1.0).max() < 0.25


def test_malformed_nuscenes_json_names_the_file(tmp_path, capsys):
    from advperc_ros.cli import main

    (tmp_path / "gt.json").write_text('{"results": {"s0": [{"detection_name": "car", "translation": [1, 2, 0]}]}}')
    (tmp_path / "r.json").write_text('{"results": {}}')
    code = main(["pem", "fit", str(tmp_path / "r.json"), "--nuscenes-gt", str(tmp_path / "gt.json"), "--output",
                 str(tmp_path / "m.json")])
    err = capsys.readouterr().err
    assert code == 2 and "gt.json" in err and "ego_translation" in err
