"""The perception error model: densities against scipy.stats, parameter recovery, sampling."""

import numpy as np
import pytest
from scipy import stats

from advperc_ros.core.pem import NUM_FEATURES, PEM, _student_t_1d_logpdf, _student_t_2d_logpdf, fit

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
