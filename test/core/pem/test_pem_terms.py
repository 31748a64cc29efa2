"""The perception error model's terms beyond the paper (false positives, flips, velocity, size,
latency, persistence): a model without them scores and samples bit for bit as before them (against
a frozen copy of that code), every term's density against an independent per-object-frame
reference built on scipy.stats, and the tensors it samples."""

import json
import math
from dataclasses import asdict, replace

import numpy as np
import pytest
from pem_scenes import EXTENDED, moving_scene
from scipy import stats
from scipy.special import expit, gammaln, log_expit
from test_pem import TRUE
from test_scores import random_case

from advperc_ros.core.geometry import wrap_angle
from advperc_ros.core.metrics.nds import DIST_THRESHOLDS, in_range, nds
from advperc_ros.core.metrics.scores import matched_errors, score
from advperc_ros.core.pem import PEM, bearings, default_pem, features
from advperc_ros.core.perception_errors import PerceptionErrors, inject
from advperc_ros.exceptions import PEMError

# ---------------------------------------------------------------- a frozen copy of the PEM before its new terms


def _old_t2(e, loc, s1, s2, rho, nu):
    z1, z2 = (e[..., 0] - loc[0]) / s1, (e[..., 1] - loc[1]) / s2
    det = 1.0 - rho * rho
    maha = (z1 * z1 - 2.0 * rho * z1 * z2 + z2 * z2) / det
    return (gammaln((nu + 2.0) / 2.0) - gammaln(nu / 2.0) - np.log(nu * np.pi)
            - np.log(s1) - np.log(s2) - 0.5 * np.log(det) - (nu + 2.0) / 2.0 * np.log1p(maha / nu))


def _old_t1(e, scale, nu):
    z = e / scale
    return (gammaln((nu + 1.0) / 2.0) - gammaln(nu / 2.0) - 0.5 * np.log(nu * np.pi) - np.log(scale)
            - (nu + 1.0) / 2.0 * np.log1p(z * z / nu))


def _old_pem_ll(m, gt, pred, ego):
    """score(...).pem_ll as the code computed it before the new terms: its matching, its densities."""
    result = nds(gt, pred, ego)
    pred_gt = result.matchings[max(DIST_THRESHOLDS)].pred_gt
    f, p = np.nonzero(pred_gt >= 0)
    g = pred_gt[f, p]
    errors = PerceptionErrors.none(*gt.shape)
    errors.fn[:] = True
    errors.fn[f, g] = False
    errors.dx[f, g], errors.dy[f, g] = pred.x[f, p] - gt.x[f, g], pred.y[f, p] - gt.y[f, g]
    errors.dyaw[f, g] = wrap_angle(pred.yaw[f, p] - gt.yaw[f, g])
    counted = result.gt_in_range
    if not counted.any():
        return float("nan")
    phi = features(gt, ego)
    bearing = bearings(gt, ego)
    c, s = np.cos(bearing), np.sin(bearing)
    rt = np.stack([c * errors.dx + s * errors.dy, -s * errors.dx + c * errors.dy], axis=-1)
    ph, detected, e, dyaw = phi[counted], ~errors.fn[counted], rt[counted], errors.dyaw[counted]
    logit = ph @ np.asarray(m.detection)
    out = np.where(detected, log_expit(logit), log_expit(-logit))
    position = _old_t2(e, np.asarray(m.position_loc), np.exp(ph @ np.asarray(m.radial_log_scale)),
                       np.exp(ph @ np.asarray(m.tangential_log_scale)), m.position_rho, m.position_nu)
    yaw = _old_t1(wrap_angle(dyaw), np.exp(ph @ np.asarray(m.yaw_log_scale)), m.yaw_nu)
    return float((out + np.where(detected, position + yaw, 0.0)).mean())


def _old_sample(m, truth, ego, rng):
    phi = features(truth, ego)
    shape = phi.shape[:-1]
    detected = rng.random(shape) < expit(phi @ np.asarray(m.detection))
    s1, s2 = np.exp(phi @ np.asarray(m.radial_log_scale)), np.exp(phi @ np.asarray(m.tangential_log_scale))
    g1, g2 = rng.standard_normal(shape), rng.standard_normal(shape)
    w = np.sqrt(rng.chisquare(m.position_nu, shape) / m.position_nu)
    rho = m.position_rho
    rt = np.stack([m.position_loc[0] + s1 * g1 / w,
                   m.position_loc[1] + s2 * (rho * g1 + np.sqrt(1.0 - rho * rho) * g2) / w], axis=-1)
    dyaw = np.exp(phi @ np.asarray(m.yaw_log_scale)) * rng.standard_t(m.yaw_nu, shape)
    bearing = bearings(truth, ego)
    c, s = np.cos(bearing), np.sin(bearing)
    return PerceptionErrors(dx=c * rt[..., 0] - s * rt[..., 1], dy=s * rt[..., 0] + c * rt[..., 1], dyaw=dyaw,
                            fn=~detected)


@pytest.mark.parametrize("model", [default_pem(), TRUE], ids=["default", "test model"])
def test_a_model_without_the_new_terms_scores_bit_for_bit_as_before(model):
    """On random outputs with offsets, drops, flips of any size and false positives of every kind."""
    rng = np.random.default_rng(7)
    for _ in range(40):
        gt, pred, ego = random_case(rng)
        old, new = _old_pem_ll(model, gt, pred, ego), score(gt, pred, ego, model).pem_ll
        assert (math.isnan(old) and math.isnan(new)) or old == new


@pytest.mark.parametrize("model", [default_pem(), TRUE], ids=["default", "test model"])
def test_a_model_without_the_new_terms_samples_bit_for_bit_as_before(model):
    truth, ego = moving_scene(np.random.default_rng(1), frames=40)
    old_rng, new_rng = np.random.default_rng(5), np.random.default_rng(5)
    old, new = _old_sample(model, truth, ego, old_rng), model.sample(truth, ego, new_rng)
    assert new.equals(old) and new.kinds == ("position", "yaw", "drop")
    assert old_rng.random() == new_rng.random()  # and drew exactly as many numbers


# ---------------------------------------------------------------- every term against scipy, object-frame by object-frame


def _reference_pem_ll(m: PEM, truth, errors, ego, counted) -> float:
    """PEM LL of read-back errors, written out per object-frame with scipy.stats: the detector shows
    the truth of `latency` frames back (not before the car's present appearance), a detection follows
    its agent's latest earlier counted detection, ghosts are Poisson per frame."""
    phi, latency = features(truth, ego), int(m.latency)
    total, count, last = 0.0, 0, {}
    for k in range(truth.shape[0]):
        for j in range(truth.shape[1]):
            if not counted[k, j]:
                continue
            count += 1
            x = phi[k, j]
            p_detect = expit(x @ np.asarray(m.detection))
            if errors.fn[k, j]:
                total += math.log(1.0 - p_detect)
                continue
            total += math.log(p_detect)
            source = k
            while k - source < latency and source > 0 and truth.valid[source - 1, j]:
                source -= 1
            b = math.atan2(truth.y[k, j] - ego[k, 1], truth.x[k, j] - ego[k, 0])
            turn = np.array([[math.cos(b), math.sin(b)], [-math.sin(b), math.cos(b)]])
            e = turn @ np.array([errors.dx[k, j] - (truth.x[source, j] - truth.x[k, j]),
                                 errors.dy[k, j] - (truth.y[source, j] - truth.y[k, j])])
            s = np.exp([x @ np.asarray(m.radial_log_scale), x @ np.asarray(m.tangential_log_scale)])
            loc = np.asarray(m.position_loc)
            shape = np.outer(s, s) * np.array([[1.0, m.position_rho], [m.position_rho, 1.0]])
            decay = m.position_ar ** (k - last[j][0]) if j in last else 0.0
            mean = loc + s * decay * (last[j][1] if j in last else 0.0)
            total += stats.multivariate_t(mean, shape * (1.0 - decay ** 2), df=m.position_nu).logpdf(e)
            last[j] = (k, (e - loc) / s)
            dyaw = errors.dyaw[k, j] - (truth.yaw[source, j] - truth.yaw[k, j])
            yaw = stats.t(df=m.yaw_nu, scale=math.exp(x @ np.asarray(m.yaw_log_scale)))
            flip = m.flip_near + (m.flip_far - m.flip_near) * min(x[1], 1.0)
            wrap = (dyaw + math.pi) % (2 * math.pi) - math.pi
            turned = (dyaw % (2 * math.pi)) - math.pi
            total += math.log((1.0 - flip) * yaw.pdf(wrap) + flip * yaw.pdf(turned))
            if m.velocity_radial_scale > 0:
                v = turn @ np.array([errors.dvx[k, j] - (truth.vx[source, j] - truth.vx[k, j]),
                                     errors.dvy[k, j] - (truth.vy[source, j] - truth.vy[k, j])])
                velocity = np.diag([m.velocity_radial_scale ** 2, m.velocity_tangential_scale ** 2])
                total += stats.multivariate_t(np.zeros(2), velocity, df=m.velocity_nu).logpdf(v)
            if m.length_log_std > 0:
                total += stats.norm(m.length_log_loc, m.length_log_std).logpdf(math.log(errors.length_scale[k, j]))
                total += stats.norm(m.width_log_loc, m.width_log_std).logpdf(math.log(errors.width_scale[k, j]))
    if m.false_positive_rate > 0:
        ghosts = errors.ghost_on.sum(axis=1)
        total += stats.poisson(m.false_positive_rate * count / truth.shape[0]).logpmf(ghosts).sum()
    return total / count


def _extended_output(model: PEM, seed: int, frames: int = 20):
    rng = np.random.default_rng(seed)
    truth, ego = moving_scene(rng, frames)
    truth.valid[:4, 1] = False  # a car that appears late: its latency reaches back only to its arrival
    truth.valid[12:15, 2] = False  # and one away for three frames: its next detection follows one 4 frames back
    return truth, inject(truth, model.sample(truth, ego, rng)), ego


@pytest.mark.parametrize("change", [
    {}, {"position_ar": 0.0}, {"position_ar": -0.4}, {"latency": 0.0}, {"latency": 5.0}, {"flip_near": 0.0},
    {"false_positive_rate": 0.0},
    {"velocity_radial_scale": 0.0, "velocity_tangential_scale": 0.0, "velocity_nu": 0.0},
    {"length_log_std": 0.0, "width_log_std": 0.0},
], ids=lambda change: ",".join(change) or "every term")
def test_every_term_scores_as_its_scipy_reference(change):
    model = replace(EXTENDED, **change)
    truth, perceived, ego = _extended_output(model, 0)
    errors, counted, _ = matched_errors(truth, perceived, ego)
    assert errors.ghost_on.any() or model.false_positive_rate == 0.0
    expected = _reference_pem_ll(model, truth, errors, ego, counted)
    assert model.score(truth, errors, ego, counted) == pytest.approx(expected, rel=1e-10)


def test_the_false_positive_term_adds_to_the_sum_not_to_the_count():
    """PEM LL is the joint log-likelihood over the counted object-frames: ghosts change the numerator."""
    truth, perceived, ego = _extended_output(EXTENDED, 0)
    errors, counted, _ = matched_errors(truth, perceived, ego)
    without = replace(EXTENDED, false_positive_rate=0.0)
    ghosts = errors.ghost_on.sum(axis=1)
    fp = stats.poisson(EXTENDED.false_positive_rate * counted.sum() / truth.shape[0]).logpmf(ghosts).sum()
    assert EXTENDED.score(truth, errors, ego, counted) == pytest.approx(
        without.score(truth, errors, ego, counted) + fp / counted.sum(), rel=1e-12)


def test_a_persistent_error_is_likelier_than_white_noise_of_the_same_size():
    truth, ego = moving_scene(np.random.default_rng(2), frames=40)
    counted = in_range(truth, ego)
    persistent, white = PerceptionErrors.none(*truth.shape), PerceptionErrors.none(*truth.shape)
    centred = replace(TRUE, position_loc=(0.0, 0.0))  # so that +0.3 m and -0.3 m are equally likely alone
    persistent.dx[:] = 0.3
    white.dx[:] = 0.3 * (-1.0) ** np.arange(truth.shape[0])[:, None]
    for model, same in ((centred, True), (replace(centred, position_ar=0.6), False)):
        a, b = (model.score(truth, e, ego, counted) for e in (persistent, white))
        assert (a == pytest.approx(b, rel=1e-12)) if same else a > b + 0.5


# ---------------------------------------------------------------- sampling


def test_samples_hold_every_kind_the_model_has_and_are_valid_tensors():
    rng = np.random.default_rng(3)
    truth, ego = moving_scene(rng, frames=200)
    errors = EXTENDED.sample(truth, ego, rng)
    assert errors.kinds == ("position", "yaw", "drop", "velocity", "size", "flip", "latency", "ghost")
    assert PerceptionErrors.from_arrays(errors.arrays()).equals(errors)
    assert (errors.latency == 2).all()
    # ghosts: Poisson with the scored mean, inside the range, moving as the scene's cars do
    mean = EXTENDED.false_positive_rate * in_range(truth, ego).sum() / truth.shape[0]
    assert errors.ghost_on.sum(axis=1).mean() == pytest.approx(mean, abs=4 * math.sqrt(mean / truth.shape[0]))
    assert (np.hypot(errors.ghost_x - ego[:, :1], errors.ghost_y - ego[:, 1:]) < 50.0).all()
    speeds = np.hypot(errors.ghost_vx, errors.ghost_vy)
    assert speeds.min() >= 5.0 - 1e-9 and speeds.max() <= 11.0 + 1e-9
    # the other kinds' marginals
    flip = EXTENDED.flip_probability(features(truth, ego))
    assert errors.flip.mean() == pytest.approx(flip.mean(), abs=4 * math.sqrt(flip.mean() / flip.size))
    assert stats.kstest(np.log(errors.length_scale).ravel(), stats.norm(0.02, 0.08).cdf).pvalue > 0.001
    radial = (np.cos(bearings(truth, ego)) * errors.dvx + np.sin(bearings(truth, ego)) * errors.dvy).ravel()
    assert stats.kstest(radial, stats.t(df=5.0, scale=0.3).cdf).pvalue > 0.001


def test_sampled_position_errors_persist_as_the_ar1():
    """Lag-1 correlation of an agent's standardised errors is the AR coefficient."""
    rng = np.random.default_rng(4)
    truth, ego = moving_scene(rng, frames=400)
    model = replace(TRUE, position_ar=0.6, position_nu=50.0, position_rho=0.0, position_loc=(0.0, 0.0))
    errors = model.sample(truth, ego, rng)
    radial = np.cos(bearings(truth, ego)) * errors.dx + np.sin(bearings(truth, ego)) * errors.dy
    z = radial / np.exp(features(truth, ego) @ np.asarray(model.radial_log_scale))
    assert np.corrcoef(z[1:].ravel(), z[:-1].ravel())[0, 1] == pytest.approx(0.6, abs=0.04)


# ---------------------------------------------------------------- model files


def test_a_model_file_without_the_new_terms_loads_with_them_off(tmp_path):
    path = tmp_path / "pem.json"
    path.write_text(json.dumps({k: v for k, v in asdict(TRUE).items() if k in {
        "detection", "position_loc", "radial_log_scale", "tangential_log_scale", "position_rho", "position_nu",
        "yaw_log_scale", "yaw_nu", "source"}}))
    assert PEM.load(path) == TRUE
    EXTENDED.save(path)
    assert PEM.load(path) == EXTENDED


@pytest.mark.parametrize("change, words", [
    ({"latency": 1.5}, ["'latency'", "a whole number"]),
    ({"latency": -1}, ["'latency'", "[0.0, 101.0)"]),
    ({"flip_far": 1.0}, ["'flip_far'", "[0.0, 1.0)"]),
    ({"position_ar": -1.0}, ["'position_ar'", "(-1.0, 1.0)"]),
    ({"false_positive_rate": -0.1}, ["'false_positive_rate'"]),
    ({"velocity_tangential_scale": 0.0}, ["'velocity_tangential_scale'", "above 0", "'velocity_radial_scale'"]),
    ({"length_log_std": 0.0}, ["'width_log_std'", "must be 0", "'length_log_std'"]),
    ({"velocity_nu": None}, ["'velocity_nu'", "a number"]),
])
def test_wrong_fields_of_the_new_terms_are_named_in_one_line(change, words, tmp_path):
    path = tmp_path / "model.json"
    path.write_text(json.dumps({**asdict(EXTENDED), **change}))
    with pytest.raises(PEMError) as caught:
        PEM.load(path)
    assert "\n" not in str(caught.value) and str(path) in str(caught.value)
    for word in words:
        assert word in str(caught.value)
