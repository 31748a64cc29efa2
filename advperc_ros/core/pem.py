"""Perception error model (PEM): p(detected | x) and p(errors | x, detected), per object-frame.

x holds, for a true box seen from the ego: range r, occlusion (occlusion.py) and footprint; the
class is always car here. The model is the paper's in kind but lighter than its residual MLP:

- detection: Bernoulli, logit linear in the features phi(x) = [1, r/50, (r/50)^2, occlusion, area/10];
- position error, in the ego's radial/tangential frame: bivariate Student-t with a fitted location,
  log-scales linear in phi(x), a constant correlation and degrees of freedom (the paper's
  multivariate Student-t, its parameters from a linear map instead of a network);
- yaw error: Student-t with a log-scale linear in phi(x).

With a handful of features a linear map already captures the trends that matter (errors and misses
growing with range and occlusion), fits in seconds with scipy, samples and scores vectorised, and
has parameters one can read. The log-likelihood of a sequence is the per object-frame mean of
log p(det | x) + [det] (log p(position error | x) + log p(yaw error | x)).
"""

import json
import math
from dataclasses import asdict, dataclass, fields
from functools import lru_cache
from importlib import resources
from pathlib import Path

import numpy as np
from scipy.optimize import minimize
from scipy.special import expit, gammaln, log_expit

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import wrap_angle
from advperc_ros.core.inputs import read_input_text
from advperc_ros.core.occlusion import occlusion
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.exceptions import PEMError

NUM_FEATURES = 5
RANGE_SCALE = 50.0


def features(truth: BoxSequence, ego_xy: np.ndarray) -> np.ndarray:
    """phi(x) per object-frame, (F, M, NUM_FEATURES); rows of empty slots are meaningless."""
    r = np.hypot(truth.x - ego_xy[:, :1], truth.y - ego_xy[:, 1:2]) / RANGE_SCALE
    occ = np.nan_to_num(occlusion(truth, ego_xy))
    area = truth.length * truth.width / 10.0
    return np.stack([np.ones_like(r), r, r * r, occ, area], axis=-1)


def bearings(truth: BoxSequence, ego_xy: np.ndarray) -> np.ndarray:
    """Bearing (rad) of every ground-truth box from the ego: the PEM's position errors are radial and
    tangential to it, as a sensor's are."""
    return np.arctan2(truth.y - ego_xy[:, 1:2], truth.x - ego_xy[:, :1])


def _student_t_2d_logpdf(e: np.ndarray, loc: np.ndarray, s1: np.ndarray, s2: np.ndarray, rho: float, nu: float):
    """log density of a bivariate t with shape matrix [[s1^2, rho s1 s2], [rho s1 s2, s2^2]]."""
    z1, z2 = (e[..., 0] - loc[0]) / s1, (e[..., 1] - loc[1]) / s2
    det = 1.0 - rho * rho
    maha = (z1 * z1 - 2.0 * rho * z1 * z2 + z2 * z2) / det
    return (
        gammaln((nu + 2.0) / 2.0) - gammaln(nu / 2.0) - np.log(nu * np.pi)
        - np.log(s1) - np.log(s2) - 0.5 * np.log(det) - (nu + 2.0) / 2.0 * np.log1p(maha / nu)
    )


def _student_t_1d_logpdf(e: np.ndarray, scale: np.ndarray, nu: float):
    z = e / scale
    return (
        gammaln((nu + 1.0) / 2.0) - gammaln(nu / 2.0) - 0.5 * np.log(nu * np.pi) - np.log(scale)
        - (nu + 1.0) / 2.0 * np.log1p(z * z / nu)
    )


@dataclass(frozen=True)
class PEM:
    """A fitted perception error model: how likely a detector is to detect an object and how its
    position and yaw errors are distributed, given the object's features. It tells typical errors
    from adversarial ones (the PEM log-likelihood objective, `check-typical`); frozen and saved as JSON
    so a report names the model it was scored with."""

    detection: tuple[float, ...]  # logit weights on phi
    position_loc: tuple[float, float]  # m, radial and tangential bias
    radial_log_scale: tuple[float, ...]  # weights on phi
    tangential_log_scale: tuple[float, ...]
    position_rho: float
    position_nu: float
    yaw_log_scale: tuple[float, ...]
    yaw_nu: float
    source: str  # where the numbers come from

    # ----- model -----
    def _linear(self, weights: tuple[float, ...], phi: np.ndarray) -> np.ndarray:
        return phi @ np.asarray(weights)

    def detection_probability(self, phi: np.ndarray) -> np.ndarray:
        return expit(self._linear(self.detection, phi))

    def log_likelihoods(self, phi: np.ndarray, detected: np.ndarray, radial_tangential: np.ndarray, dyaw: np.ndarray):
        """Per object-frame log p(det | x) + [det] log p(errors | x)."""
        logit = self._linear(self.detection, phi)
        out = np.where(detected, log_expit(logit), log_expit(-logit))
        position = _student_t_2d_logpdf(
            radial_tangential, np.asarray(self.position_loc),
            np.exp(self._linear(self.radial_log_scale, phi)), np.exp(self._linear(self.tangential_log_scale, phi)),
            self.position_rho, self.position_nu,
        )
        yaw = _student_t_1d_logpdf(wrap_angle(dyaw), np.exp(self._linear(self.yaw_log_scale, phi)), self.yaw_nu)
        return out + np.where(detected, position + yaw, 0.0)

    # ----- use on scenarios -----
    def score(
        self, truth: BoxSequence, errors: PerceptionErrors, ego_xy: np.ndarray, counted: np.ndarray,
        phi: np.ndarray | None = None,
    ) -> float:
        """Mean log-likelihood of the errors over the counted object-frames (present and in range);
        phi = features(truth, ego_xy) may be passed in when scoring many errors on one rollout."""
        if not counted.any():
            return float("nan")
        phi = features(truth, ego_xy) if phi is None else phi
        bearing = bearings(truth, ego_xy)
        c, s = np.cos(bearing), np.sin(bearing)
        rt = np.stack([c * errors.dx + s * errors.dy, -s * errors.dx + c * errors.dy], axis=-1)
        ll = self.log_likelihoods(phi[counted], ~errors.fn[counted], rt[counted], errors.dyaw[counted])
        return float(ll.mean())

    def sample_features(self, phi: np.ndarray, rng: np.random.Generator):
        """(detected, radial/tangential position errors (..., 2), yaw errors) drawn for features phi."""
        shape = phi.shape[:-1]
        detected = rng.random(shape) < self.detection_probability(phi)
        s1 = np.exp(self._linear(self.radial_log_scale, phi))
        s2 = np.exp(self._linear(self.tangential_log_scale, phi))
        g1, g2 = rng.standard_normal(shape), rng.standard_normal(shape)
        w = np.sqrt(rng.chisquare(self.position_nu, shape) / self.position_nu)  # Student-t = normal / sqrt(chi2/nu)
        rho = self.position_rho
        rt = np.stack([self.position_loc[0] + s1 * g1 / w,
                       self.position_loc[1] + s2 * (rho * g1 + np.sqrt(1.0 - rho * rho) * g2) / w], axis=-1)
        dyaw = np.exp(self._linear(self.yaw_log_scale, phi)) * rng.standard_t(self.yaw_nu, shape)
        return detected, rt, dyaw

    def sample(self, truth: BoxSequence, ego_xy: np.ndarray, rng: np.random.Generator) -> PerceptionErrors:
        """An error tensor drawn from the model for the given truth and ego positions."""
        detected, rt, dyaw = self.sample_features(features(truth, ego_xy), rng)
        bearing = bearings(truth, ego_xy)
        c, s = np.cos(bearing), np.sin(bearing)
        dx = c * rt[..., 0] - s * rt[..., 1]
        dy = s * rt[..., 0] + c * rt[..., 1]
        return PerceptionErrors(dx=dx, dy=dy, dyaw=dyaw, fn=~detected)

    # ----- persistence -----
    def save(self, path: Path) -> None:
        Path(path).write_text(json.dumps(asdict(self), indent=2) + "\n")

    @classmethod
    def load(cls, path: Path) -> "PEM":
        try:
            text = read_input_text(Path(path))
        except (OSError, UnicodeDecodeError) as exc:
            raise PEMError(f"{path}: cannot read the model: {exc}") from None
        return cls.from_json(text, str(path))

    @classmethod
    def from_json(cls, text: str, source: str) -> "PEM":
        """The model of a JSON text as `save` writes it; `source` (its file) prefixes any error.
        Every field is checked here, so a wrong model fails on loading, not inside a rollout."""
        try:
            data = json.loads(text)
        except (ValueError, RecursionError) as exc:  # RecursionError: arrays nested too deep
            raise PEMError(f"{source}: not JSON: {exc}") from None
        if not isinstance(data, dict):
            raise PEMError(f"{source}: not a JSON object")
        names = [f.name for f in fields(cls)]
        unknown = sorted(set(data) - set(names))
        if unknown:
            raise PEMError(f"{source}: field {unknown[0]!r} is unknown (fields: {', '.join(names)})")
        values = {name: _checked(data.get(name), name, source) for name in names}
        return cls(**values)


# field -> (how many numbers, or None for a single one; lowest value allowed (exclusive); highest)
_FIELD_SHAPES = {
    "detection": (NUM_FEATURES, -math.inf, math.inf),
    "position_loc": (2, -math.inf, math.inf),
    "radial_log_scale": (NUM_FEATURES, -math.inf, math.inf),
    "tangential_log_scale": (NUM_FEATURES, -math.inf, math.inf),
    "position_rho": (None, -1.0, 1.0),
    "position_nu": (None, 0.0, math.inf),
    "yaw_log_scale": (NUM_FEATURES, -math.inf, math.inf),
    "yaw_nu": (None, 0.0, math.inf),
}


def _checked(value, name: str, source: str):
    """A field's JSON value as the model holds it, or a PEMError saying what the field must be."""
    if name == "source":
        if not isinstance(value, str):
            raise PEMError(f"{source}: field 'source' must be a string")
        return value
    count, low, high = _FIELD_SHAPES[name]
    items = [value] if count is None else value if isinstance(value, list) and len(value) == count else [None]
    numbers = [_number(item) for item in items]
    if not all(number is not None and low < number < high for number in numbers):
        what = "a number" if count is None else f"a list of {count} numbers"
        bounds = f" in ({low}, {high})" if count is None else ", finite"
        shown = (f"a list of {len(value)}" if isinstance(value, list) else "an object" if isinstance(value, dict)
                 else f"{value!r:.60}")
        raise PEMError(f"{source}: field '{name}' must be {what}{bounds}, not {shown}")
    return numbers[0] if count is None else tuple(numbers)


def _number(value) -> float | None:
    """A JSON number as a float; None for anything else (booleans, strings, ints beyond a float)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        return float(value)
    except OverflowError:
        return None


@lru_cache(maxsize=1)
def default_pem() -> PEM:
    """The shipped reference model (advperc_ros/data/default_pem.json; its `source` says what it is)."""
    return PEM.from_json(resources.files("advperc_ros").joinpath("data/default_pem.json").read_text(), "default_pem.json")


def fit(phi: np.ndarray, detected: np.ndarray, radial_tangential: np.ndarray, dyaw: np.ndarray, source: str) -> PEM:
    """Maximum-likelihood fit from paired object-frames: phi (K, F), detected (K,), errors of the
    detected ones (K, 2) and (K,) (values of missed ones are ignored)."""
    k = NUM_FEATURES

    def detection_nll(w):
        logit = phi @ w
        return -np.mean(np.where(detected, log_expit(logit), log_expit(-logit)))

    det = minimize(detection_nll, np.zeros(k), method="L-BFGS-B").x
    p, e, y = phi[detected], radial_tangential[detected], wrap_angle(dyaw[detected])

    def position_nll(theta):
        loc, br, bt = theta[:2], theta[2 : 2 + k], theta[2 + k : 2 + 2 * k]
        rho, nu = np.tanh(theta[-2]), 2.0 + np.exp(theta[-1])
        return -np.mean(_student_t_2d_logpdf(e, loc, np.exp(p @ br), np.exp(p @ bt), rho, nu))

    start = np.concatenate([[0.0, 0.0], [np.log(e[:, 0].std() + 1e-6)] + [0.0] * (k - 1),
                            [np.log(e[:, 1].std() + 1e-6)] + [0.0] * (k - 1), [0.0, np.log(3.0)]])
    pos = minimize(position_nll, start, method="L-BFGS-B").x

    def yaw_nll(theta):
        return -np.mean(_student_t_1d_logpdf(y, np.exp(p @ theta[:k]), 2.0 + np.exp(theta[-1])))

    yaw = minimize(yaw_nll, np.concatenate([[np.log(y.std() + 1e-6)], np.zeros(k - 1), [np.log(3.0)]]),
                   method="L-BFGS-B").x
    return PEM(
        detection=tuple(det),
        position_loc=(float(pos[0]), float(pos[1])),
        radial_log_scale=tuple(pos[2 : 2 + k]),
        tangential_log_scale=tuple(pos[2 + k : 2 + 2 * k]),
        position_rho=float(np.tanh(pos[-2])),
        position_nu=float(2.0 + np.exp(pos[-1])),
        yaw_log_scale=tuple(yaw[:k]),
        yaw_nu=float(2.0 + np.exp(yaw[-1])),
        source=source,
    )
