"""The perception error model's features and densities: what an object-frame is to the model (its
features, the radial/tangential frame of its errors) and the distributions its terms are made of.
Shared by the model (scoring, sampling) and the fit (objectives and their gradients)."""

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import gammaln

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.occlusion import occlusion

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


def to_radial(dx: np.ndarray, dy: np.ndarray, bearing: np.ndarray) -> np.ndarray:
    """World-frame vectors (..., 2 given as x and y) turned into the radial/tangential frame of `bearing`."""
    c, s = np.cos(bearing), np.sin(bearing)
    return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)


def to_world(rt: np.ndarray, bearing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`to_radial` undone: the world-frame x and y of radial/tangential vectors (..., 2)."""
    c, s = np.cos(bearing), np.sin(bearing)
    return c * rt[..., 0] - s * rt[..., 1], s * rt[..., 0] + c * rt[..., 1]


def _student_t_2d_logpdf(e: np.ndarray, loc, s1, s2, rho: float, nu: float):
    """log density of a bivariate t with shape matrix [[s1^2, rho s1 s2], [rho s1 s2, s2^2]]; loc is
    one location (2,) or one per row (..., 2)."""
    loc = np.asarray(loc)
    z1, z2 = (e[..., 0] - loc[..., 0]) / s1, (e[..., 1] - loc[..., 1]) / s2
    det = 1.0 - rho * rho
    maha = (z1 * z1 - 2.0 * rho * z1 * z2 + z2 * z2) / det
    return (
        gammaln((nu + 2.0) / 2.0) - gammaln(nu / 2.0) - np.log(nu * np.pi)
        - np.log(s1) - np.log(s2) - 0.5 * np.log(det) - (nu + 2.0) / 2.0 * np.log1p(maha / nu)
    )


def _student_t_1d_logpdf(e: np.ndarray, scale, nu: float):
    z = e / scale
    return (
        gammaln((nu + 1.0) / 2.0) - gammaln(nu / 2.0) - 0.5 * np.log(nu * np.pi) - np.log(scale)
        - (nu + 1.0) / 2.0 * np.log1p(z * z / nu)
    )


def _normal_logpdf(e: np.ndarray, loc: float, scale: float):
    z = (e - loc) / scale
    return -0.5 * z * z - math.log(scale) - 0.5 * math.log(2.0 * math.pi)


def _flip_mixture(straight: np.ndarray, flipped: np.ndarray, p: np.ndarray) -> np.ndarray:
    """log((1 - p) exp(straight) + p exp(flipped)); p may be 0 (no flip where it is)."""
    with np.errstate(divide="ignore"):
        return np.logaddexp(np.log1p(-p) + straight, np.log(p) + flipped)


@dataclass(frozen=True)
class _Persistence:
    """An agent's position errors as the AR(1) of their standardised values z = (e - loc) / scale sees
    them: the innovation r = (z - d z_prev) / c of each row, d = a^gap the decay since the row it
    follows (0 for a row that follows none) and c = sqrt(1 - d^2). log p(e) = log t(r; 0, 1, rho, nu)
    - log s1 - log s2 - 2 log c: what both scoring and the fit compute."""

    z: np.ndarray  # (K, 2)
    previous_z: np.ndarray  # (K, 2), 0 where none
    decay: np.ndarray  # (K,)
    spread: np.ndarray  # (K,) c
    innovation: np.ndarray  # (K, 2) r

    @classmethod
    def of(cls, rt: np.ndarray, loc, scales: np.ndarray, a: float, previous: np.ndarray, gap: np.ndarray):
        z = (rt - loc) / scales
        has = previous >= 0
        decay = np.where(has, a ** np.where(has, gap, 1), 0.0)
        previous_z = np.where(has[:, None], z[np.maximum(previous, 0)], 0.0)
        spread = np.sqrt(1.0 - decay * decay)
        return cls(z, previous_z, decay, spread, (z - decay[:, None] * previous_z) / spread[:, None])

    def log_density(self, scales: np.ndarray, rho: float, nu: float) -> np.ndarray:
        return (_student_t_2d_logpdf(self.innovation, np.zeros(2), 1.0, 1.0, rho, nu) - np.log(scales).sum(axis=-1)
                - 2.0 * np.log(self.spread))
