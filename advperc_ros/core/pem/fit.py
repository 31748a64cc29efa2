"""Fitting a perception error model by maximum likelihood: each part's objective (with exact
gradients where a fit would otherwise take many evaluations) and the fit of every part from the
object-frames of a labelled log."""

import math
from dataclasses import replace
from typing import Any

import numpy as np
from scipy.optimize import minimize
from scipy.special import digamma, log_expit

from advperc_ros.core.geometry import wrap_angle
from advperc_ros.core.pem.densities import (
    NUM_FEATURES,
    _flip_mixture,
    _Persistence,
    _student_t_1d_logpdf,
    _student_t_2d_logpdf,
)
from advperc_ros.core.pem.frames import ObjectFrames
from advperc_ros.core.pem.model import PEM
from advperc_ros.core.perception_errors import ErrorSpace

FIT_LATENCIES = ErrorSpace().max_latency  # a fit tries latencies 0..this, the error space's own bound
SCALE_FLOOR = 1e-3  # smallest velocity scale (m/s) and size std a fit gives: a log without such errors is no
# zero-width model


def _fit_detection(phi: np.ndarray, detected: np.ndarray) -> np.ndarray:
    def detection_nll(w):
        logit = phi @ w
        return -np.mean(np.where(detected, log_expit(logit), log_expit(-logit)))

    return minimize(detection_nll, np.zeros(NUM_FEATURES), method="L-BFGS-B").x


def _t2_gradients(e: np.ndarray, loc: np.ndarray, s1: np.ndarray | float, s2: np.ndarray | float, rho: float,
                  nu: float):
    """d log p / d(loc (K, 2), log s1, log s2, rho, nu) of `_student_t_2d_logpdf`, per row: what lets
    the position fit take exact gradients instead of 15 evaluations for each."""
    z1, z2 = (e[:, 0] - loc[0]) / s1, (e[:, 1] - loc[1]) / s2
    det = 1.0 - rho * rho
    maha = (z1 * z1 - 2.0 * rho * z1 * z2 + z2 * z2) / det
    d_maha = -(nu + 2.0) / (2.0 * (nu + maha))
    d_z1, d_z2 = d_maha * 2.0 * (z1 - rho * z2) / det, d_maha * 2.0 * (z2 - rho * z1) / det
    d_rho = rho / det + d_maha * (-2.0 * z1 * z2 + 2.0 * rho * maha) / det
    d_nu = (0.5 * digamma((nu + 2.0) / 2.0) - 0.5 * digamma(nu / 2.0) - 1.0 / nu - 0.5 * np.log1p(maha / nu)
            + (nu + 2.0) / 2.0 * maha / (nu * (nu + maha)))
    return np.stack([-d_z1 / s1, -d_z2 / s2], axis=-1), -1.0 - d_z1 * z1, -1.0 - d_z2 * z2, d_rho, d_nu


def _t1_gradients(e: np.ndarray, scale: np.ndarray, nu: float):
    """d log p / d(log scale, nu) of `_student_t_1d_logpdf`, per row."""
    z2 = (e / scale) ** 2
    d_log_scale = -1.0 + (nu + 1.0) * z2 / (nu + z2)
    d_nu = (0.5 * digamma((nu + 1.0) / 2.0) - 0.5 * digamma(nu / 2.0) - 0.5 / nu - 0.5 * np.log1p(z2 / nu)
            + (nu + 1.0) / 2.0 * z2 / (nu * (nu + z2)))
    return d_log_scale, d_nu


def _position_objective(theta: np.ndarray, p: np.ndarray, e: np.ndarray, previous: np.ndarray, gap: np.ndarray
                        ) -> tuple[float, np.ndarray]:
    """Mean negative log-likelihood of position errors e (K, 2) at features p, each given the row
    `previous` it follows (`_Persistence`), and its gradient, in theta = (loc, radial log-scale
    weights, tangential ones, atanh rho, log(nu - 2)[, atanh a]): without the last, a = 0 (every row
    independent, the marginal t)."""
    k = NUM_FEATURES
    loc, rho, nu = theta[:2], np.tanh(theta[2 + 2 * k]), 2.0 + np.exp(theta[3 + 2 * k])
    a = np.tanh(theta[4 + 2 * k]) if len(theta) > 4 + 2 * k else 0.0
    scales = np.exp(np.stack([p @ theta[2 : 2 + k], p @ theta[2 + k : 2 + 2 * k]], axis=-1))
    chain = _Persistence.of(e, loc, scales, a, previous, gap)
    d_innovation, _, _, d_rho, d_nu = _t2_gradients(chain.innovation, np.zeros(2), 1.0, 1.0, rho, nu)
    d_innovation = -d_innovation  # _t2_gradients gives d/d(loc) = -d/d(innovation) at unit scales
    spread = chain.spread[:, None]
    d_z, d_previous_z = d_innovation / spread, -d_innovation * chain.decay[:, None] / spread
    has = previous >= 0
    d_log_scales = -1.0 - d_z * chain.z  # z = (e - loc) / s: dz / d log s = -z, and -log s itself
    np.add.at(d_log_scales, previous[has], -d_previous_z[has] * chain.previous_z[has])
    previous_scales = scales[np.maximum(previous, 0)]
    d_loc = -(d_z / scales).sum(axis=0) - (d_previous_z[has] / previous_scales[has]).sum(axis=0)
    grad = [d_loc / len(e), d_log_scales[:, 0] @ p / len(e), d_log_scales[:, 1] @ p / len(e),
            [d_rho.mean() * (1.0 - rho * rho), d_nu.mean() * (nu - 2.0)]]
    if len(theta) > 4 + 2 * k:
        d_decay = ((d_innovation * (-chain.previous_z / spread + chain.innovation * chain.decay[:, None] / spread ** 2))
                   .sum(axis=1) + 2.0 * chain.decay / chain.spread ** 2)
        d_a = np.where(has, gap * a ** np.where(has, gap - 1, 0), 0.0)
        grad.append([np.mean(d_decay * d_a) * (1.0 - a * a)])
    return -float(np.mean(chain.log_density(scales, rho, nu))), -np.concatenate(grad)


def _yaw_objective(theta: np.ndarray, p: np.ndarray, y: np.ndarray) -> tuple[float, np.ndarray]:
    """Mean negative log-likelihood of yaw errors y (K,) under the flip mixture, and its gradient, in
    theta = (log-scale weights, log(nu - 2), flip probability near, far)."""
    k = NUM_FEATURES
    scale, nu = np.exp(p @ theta[:k]), 2.0 + np.exp(theta[k])
    reach = np.minimum(p[:, 1], 1.0)
    flip = theta[k + 1] + (theta[k + 2] - theta[k + 1]) * reach
    turned = wrap_angle(y - np.pi)
    straight, flipped = _student_t_1d_logpdf(y, scale, nu), _student_t_1d_logpdf(turned, scale, nu)
    mixture = _flip_mixture(straight, flipped, flip)
    share_straight, share_flipped = np.exp(straight - mixture), np.exp(flipped - mixture)  # density ratios
    d_scale_s, d_nu_s = _t1_gradients(y, scale, nu)
    d_scale_f, d_nu_f = _t1_gradients(turned, scale, nu)
    w_s, w_f = (1.0 - flip) * share_straight, flip * share_flipped  # each component's responsibility
    d_flip = share_flipped - share_straight
    grad = np.concatenate([(w_s * d_scale_s + w_f * d_scale_f) @ p / len(y),
                           [np.mean(w_s * d_nu_s + w_f * d_nu_f) * (nu - 2.0),
                            np.mean(d_flip * (1.0 - reach)), np.mean(d_flip * reach)]])
    return -float(np.mean(mixture)), -grad


def _fit_position(p: np.ndarray, e: np.ndarray, previous: np.ndarray, gap: np.ndarray,
                  persistent: bool) -> dict[str, Any]:
    """The position fields fitted to detected errors e (K, 2) at features p, the AR coefficient too if
    `persistent` (rows following `previous`, `gap` frames back)."""
    k = NUM_FEATURES
    theta = np.concatenate([[0.0, 0.0], [np.log(e[:, 0].std() + 1e-6)] + [0.0] * (k - 1),
                            [np.log(e[:, 1].std() + 1e-6)] + [0.0] * (k - 1), [0.0, np.log(3.0)]]
                           + ([[0.0]] if persistent else []))
    theta = minimize(_position_objective, theta, args=(p, e, previous, gap), jac=True, method="L-BFGS-B").x
    return {
        "position_loc": (float(theta[0]), float(theta[1])),
        "radial_log_scale": tuple(float(v) for v in theta[2 : 2 + k]),
        "tangential_log_scale": tuple(float(v) for v in theta[2 + k : 2 + 2 * k]),
        "position_rho": float(np.tanh(theta[2 + 2 * k])),
        "position_nu": float(2.0 + np.exp(theta[3 + 2 * k])),
        "position_ar": float(np.tanh(theta[4 + 2 * k])) if persistent else 0.0,
    }


def _fit_yaw(p: np.ndarray, y: np.ndarray) -> dict[str, Any]:
    """The yaw and flip fields fitted to detected yaw errors y (K,) at features p. Flip probabilities
    stay in [0, 1/2]: beyond, `flipped` would be the straight component."""
    k = NUM_FEATURES
    y = wrap_angle(y)
    straight = y[np.abs(y) < np.pi / 2] if np.any(np.abs(y) < np.pi / 2) else y  # the t starts at their spread
    theta = np.concatenate([[np.log(straight.std() + 1e-6)], np.zeros(k - 1), [np.log(3.0), 0.01, 0.01]])
    bounds = [(None, None)] * (k + 1) + [(0.0, 0.5)] * 2
    theta = minimize(_yaw_objective, theta, args=(p, y), jac=True, method="L-BFGS-B", bounds=bounds).x
    return {"yaw_log_scale": tuple(float(v) for v in theta[:k]), "yaw_nu": float(2.0 + np.exp(theta[k])),
            "flip_near": float(theta[k + 1]), "flip_far": float(theta[k + 2])}


def fit(phi: np.ndarray, detected: np.ndarray, radial_tangential: np.ndarray, dyaw: np.ndarray, source: str) -> PEM:
    """Maximum-likelihood fit of the per-object-frame parts from paired object-frames: phi (K, F),
    detected (K,), errors of the detected ones (K, 2) and (K,) (values of missed ones are ignored):
    detection, position (every row independent), and yaw with its heading flips (the flips' mixture
    is what keeps a flipped detection from passing for a huge yaw error of the t)."""
    p, independent = phi[detected], np.full(np.count_nonzero(detected), -1)
    return PEM(detection=tuple(float(v) for v in _fit_detection(phi, detected)), source=source,
               **_fit_position(p, radial_tangential[detected], independent, independent, persistent=False),
               **_fit_yaw(p, dyaw[detected]))


def _fit_latency(model: PEM, frames: ObjectFrames) -> int:
    """The latency whose lagged position errors the model's (latency-0) position density finds likeliest.
    A wrong latency adds the agents' own motion to the errors, and a symmetric unimodal density's
    expected log rates an offset error lower than the centred one (Anderson's inequality), so the
    fitted density needs no refit per candidate."""
    rows = frames.detected
    independent = np.full(np.count_nonzero(rows), -1)
    latencies = [0, *sorted(frames.lags)]
    scores = [model.position_log_density(frames.lagged(latency)[0][rows], frames.phi[rows], independent,
                                         independent).sum() for latency in latencies]
    return latencies[int(np.argmax(scores))]


def _detected_chain(frames: ObjectFrames) -> tuple[np.ndarray, np.ndarray]:
    """(previous, gap) of the detected rows, numbered among themselves (a previous row is a detected one)."""
    rows = np.flatnonzero(frames.detected)
    renumber = np.full(len(frames.detected), -1)
    renumber[rows] = np.arange(rows.size)
    return np.where(frames.previous[rows] >= 0, renumber[np.maximum(frames.previous[rows], 0)], -1), frames.gap[rows]


def _fit_velocity(velocity: np.ndarray) -> tuple[float, float, float]:
    """(radial scale, tangential scale, degrees of freedom) of the bivariate t of velocity errors;
    scales no smaller than SCALE_FLOOR, degrees of freedom in (2, 1000]."""

    def nll(theta):
        return -np.mean(_student_t_2d_logpdf(velocity, np.zeros(2), np.exp(theta[0]), np.exp(theta[1]), 0.0,
                                             2.0 + np.exp(theta[2])))

    floor = math.log(SCALE_FLOOR)
    start = [max(np.log(velocity[:, 0].std() + 1e-12), floor), max(np.log(velocity[:, 1].std() + 1e-12), floor),
             np.log(3.0)]
    theta = minimize(nll, start, method="L-BFGS-B", bounds=[(floor, None), (floor, None), (None, np.log(998.0))]).x
    return float(np.exp(theta[0])), float(np.exp(theta[1])), float(2.0 + np.exp(theta[2]))


def fit_object_frames(frames: ObjectFrames, source: str, tracked: bool = True) -> PEM:
    """Every part of the model from the object-frames of a labelled log (`object_frames` with the lags
    of latencies 0..FIT_LATENCIES): the per-object-frame parts (`fit`); the likeliest latency, with
    position and yaw fitted again from the truth it shows, the position jointly with its persistence
    (the model's own likelihood: a marginal fit would mistake the AR's averaged innovations for lighter
    tails); velocity; sizes (the normal's ML); and the false-positive rate, (count + 1/2) /
    object-frames (Jeffreys' posterior mean, so a log without ghosts still gives a model that finds
    them unlikely, not one that ignores them). `tracked`: whether a slot is one agent across frames;
    without, latency and persistence cannot be told and stay off."""
    model = fit(frames.phi, frames.detected, frames.position, frames.dyaw, source)
    latency = _fit_latency(model, frames) if tracked else 0
    detected = frames.detected
    position, dyaw, velocity = frames.lagged(latency)
    if latency:  # fitted again from scratch: the latency-0 fit's tails were those of the agents' motion
        model = replace(model, **_fit_yaw(frames.phi[detected], dyaw[detected]))
    if tracked:
        previous, gap = _detected_chain(frames)
        model = replace(model, **_fit_position(frames.phi[detected], position[detected], previous, gap,
                                               persistent=True))
    radial, tangential, nu = _fit_velocity(velocity[detected])
    log_size = frames.log_size[detected & np.isfinite(frames.log_size).all(axis=1)]  # a zero-sized box says nothing
    sizes = np.maximum(log_size.std(axis=0), SCALE_FLOOR)
    return replace(
        model, latency=float(latency), velocity_radial_scale=radial, velocity_tangential_scale=tangential,
        velocity_nu=nu, length_log_loc=float(log_size[:, 0].mean()), length_log_std=float(sizes[0]),
        width_log_loc=float(log_size[:, 1].mean()), width_log_std=float(sizes[1]),
        false_positive_rate=float((frames.false_positives.sum() + 0.5) / len(detected)),
    )
