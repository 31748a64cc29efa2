"""The shipped default models: the paper's kinds keep the hand-specified one (no published PEM LL
moves); any other kind gets the one calibrated on a real detector's published statistics, whose
numbers are derived here again from what was published."""

import math

import numpy as np
import pytest
from pem_scenes import moving_scene
from scipy.integrate import quad
from scipy.optimize import brentq, least_squares
from scipy.special import expit, gammaln
from scipy.stats import norm

from advperc_ros.core.pem import default_pem, features
from advperc_ros.core.perception_errors import ERROR_KINDS, PAPER_KINDS, PerceptionErrors

# TakaHoribe/perception_fitting, data/Vehicle/fitted_results: per bin <10, <20, <40, <60 m
BINS = ((0.0, 10.0), (10.0, 20.0), (20.0, 40.0), (40.0, 60.0))
TP_SHARE = (0.9883341110592628, 0.9254230764971644, 0.765758505373322, 0.6093500772459086)
RADIAL_STD = (0.1746766035112038, 0.19858747160448428, 0.3309955615021771, 0.45794203108112536)
RADIAL_MEAN = (-0.0614998260061017, -0.041937192553864674, -0.07111050855510798, -0.09499291602239261)
YAW_STD = (0.0304309209711959, 0.03433760392801394, 0.054950666274782664, 0.07833802246196445)
FLIP_SHARE = (0.0, 0.00109371784522465, 0.006123179222026981, 0.00288916848089242)
FP_SHARE = (0.0069995333644423, 0.029001975784557064, 0.08560183299359868, 0.09632833746618315)
AMPLITUDE, DECAY, OFFSET = 0.3505134642171963, 0.4416262072804732, 0.2031033046760538  # fitted_time_dist_err_phi
# TransFusion-L, nuScenes test set, class car
CAR_ASE, CAR_AVE = 0.148, 0.259
DISC = np.array([100.0, 300.0, 1200.0, 900.0]) / 2500.0  # the bins' shares of the 50 m disc's area
EXTENDED = default_pem(ERROR_KINDS)


def bin_mean(f, low: float, high: float) -> float:
    """f's mean over the annulus low <= r < high, by area."""
    return quad(lambda r: f(r) * r, low, high)[0] / quad(lambda r: r, low, high)[0]


def least_squares_fit(link, inverse, target, terms):
    """Weights of `terms`(r / 50) under `inverse` whose bin means are `target`'s, least squares."""
    def residuals(b):
        return [bin_mean(lambda r: inverse(np.dot(b, terms(r / 50.0))), *edges) - t for edges, t in zip(BINS, target)]

    return least_squares(residuals, [link(target[0])] + [0.0] * (len(terms(0.0)) - 1)).x


def quadratic(u):
    return [1.0, u, u * u]


def test_the_paper_kinds_keep_the_hand_specified_model_and_others_get_the_calibrated_one():
    assert default_pem() is default_pem(PAPER_KINDS) is default_pem(("yaw", "drop"))
    assert "hand-specified" in default_pem().source
    for kinds in (ERROR_KINDS, ("ghost",), ("position", "velocity")):
        assert default_pem(kinds) is EXTENDED
    assert "perception_fitting" in EXTENDED.source and "not documented" in EXTENDED.source
    assert "TransFusion" in EXTENDED.source
    assert EXTENDED.models_flips and EXTENDED.models_velocity and EXTENDED.models_size
    assert EXTENDED.false_positive_rate > 0.0 and EXTENDED.position_ar > 0.0 and EXTENDED.latency == 0.0


def test_detection_falls_with_range_and_its_recall_is_the_published_tp_share():
    car = 4.5 * 1.9 / 10.0

    def detection(r):
        return float(EXTENDED.detection_probability(np.array([1.0, r / 50.0, (r / 50.0) ** 2, 0.0, car])))

    assert np.all(np.diff([detection(r) for r in np.linspace(0.0, 50.0, 101)]) < 0.0)
    for edges, published in zip(BINS, TP_SHARE):
        assert bin_mean(detection, *edges) == pytest.approx(published, abs=0.015), edges  # a quadratic logit's fit


def test_the_default_is_the_published_statistics_derived_as_its_source_says():
    def logit(p):
        return math.log(p / (1.0 - p))

    detection = least_squares_fit(logit, expit, TP_SHARE, quadratic)
    radial = least_squares_fit(math.log, np.exp, [s * math.sqrt(3.0 / 5.0) for s in RADIAL_STD], quadratic)  # t, nu 5
    yaw = least_squares_fit(math.log, np.exp, [s * math.sqrt(2.0 / 4.0) for s in YAW_STD], quadratic)  # t, nu 4
    assert EXTENDED.detection == pytest.approx([*detection, 0.0, 0.0], abs=1e-4)
    assert EXTENDED.radial_log_scale == pytest.approx([*radial, 0.0, 0.0], abs=1e-4)
    assert EXTENDED.tangential_log_scale == EXTENDED.radial_log_scale
    assert EXTENDED.yaw_log_scale == pytest.approx([*yaw, 0.0, 0.0], abs=1e-4)
    assert (EXTENDED.position_nu, EXTENDED.yaw_nu, EXTENDED.position_rho) == (5.0, 4.0, 0.0)
    assert EXTENDED.position_loc == pytest.approx((DISC @ RADIAL_MEAN, 0.0), abs=1e-6)

    def flip_residuals(x):
        near, far = x
        return [bin_mean(lambda r: near + (far - near) * min(r / 50.0, 1.0), *edges) - share
                for edges, share in zip(BINS, FLIP_SHARE)]

    flip = least_squares(flip_residuals, [0.001, 0.005], bounds=([0.0, 0.0], [1.0, 1.0])).x
    assert (EXTENDED.flip_near, EXTENDED.flip_far) == pytest.approx(flip, abs=1e-5)
    share = np.array(FP_SHARE)
    assert EXTENDED.false_positive_rate == pytest.approx(DISC @ (share / (1.0 - share)), abs=1e-6)
    assert EXTENDED.position_ar == pytest.approx(AMPLITUDE * math.exp(-DECAY * 0.1) + OFFSET, abs=1e-6)


def test_velocity_and_size_errors_average_the_published_nuscenes_errors():
    nu = EXTENDED.velocity_nu  # E|bivariate t| = scale * E|normal pair| * E[1 / sqrt(chi2 / nu)]
    mean_norm = math.sqrt(math.pi / 2.0) * math.sqrt(nu / 2.0) * math.exp(gammaln((nu - 1.0) / 2.0) - gammaln(nu / 2.0))
    assert EXTENDED.velocity_radial_scale == EXTENDED.velocity_tangential_scale
    assert EXTENDED.velocity_radial_scale * mean_norm == pytest.approx(CAR_AVE, abs=1e-3)
    z = norm.ppf((np.arange(60) + 0.5) / 60)  # three sides' log errors on a midpoint grid of the normal

    def scale_error(sigma):
        side = np.exp(sigma * z)
        least = np.minimum(side, 1.0)
        inter = least[:, None, None] * least[None, :, None] * least[None, None, :]
        volume = side[:, None, None] * side[None, :, None] * side[None, None, :]
        return float(np.mean(1.0 - inter / (1.0 + volume - inter)))

    assert EXTENDED.length_log_std == EXTENDED.width_log_std
    assert EXTENDED.length_log_std == pytest.approx(brentq(lambda s: scale_error(s) - CAR_ASE, 0.01, 0.5), abs=1e-3)


def test_the_default_samples_every_kind_it_models():
    rng = np.random.default_rng(0)
    truth, ego = moving_scene(rng, frames=300)
    errors = EXTENDED.sample(truth, ego, rng)
    assert errors.kinds == ("position", "yaw", "drop", "velocity", "size", "flip", "ghost")  # latency 0: no lag
    assert PerceptionErrors.from_arrays(errors.arrays()).equals(errors)
    assert errors.ghost_on.any() and errors.flip.any()
    assert np.isfinite(EXTENDED.score(truth, errors, ego, truth.valid, features(truth, ego)))
