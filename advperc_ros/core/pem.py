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

Beyond the paper, the failure modes real detectors have, each an optional term that is off at its
neutral value (a model without it scores and samples exactly as the paper's parts alone):

- false positives: the in-range detections no truth matched, Poisson per frame with mean
  `false_positive_rate` x (counted object-frames / frames) of the sequence: ghosts per true
  object-frame, the ratio published detector statistics give. Its log-likelihood is summed over the
  frames and added to the object-frames' before the mean, so PEM LL stays the sequence's joint
  log-likelihood per counted object-frame (one denominator, whatever the ghosts);
- heading flip: the yaw density becomes (1 - p) t(dyaw) + p t(wrap(dyaw - pi)), p linear in range
  from `flip_near` (at the ego) to `flip_far` (at 50 m);
- velocity error, radial/tangential: bivariate Student-t with constant scales (`velocity_*`);
- size error: log(length scale) and log(width scale) independent normals (a box regressor's size
  error is bounded, and the published statistic, ASE, fixes one scale and no tail);
- latency: the detector shows the truth of `latency` frames earlier (`latency_source`, as the error
  tensor's latency kind), so every error is measured from that truth: the agent's own motion over
  the latency is the errors' expected value, not an error;
- persistence: the standardised position errors z = (e - loc) / scale of an agent's consecutive
  detections follow an AR(1), z_k = a^m z_prev + sqrt(1 - a^2m) eps (m frames apart, eps the
  bivariate t), so a persistent error is likelier than white noise of the same size; a = 0 is white.
"""

import json
import math
from dataclasses import asdict, dataclass, fields, replace
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import minimize
from scipy.special import digamma, expit, gammaln, log_expit, xlogy

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import wrap_angle
from advperc_ros.core.inputs import read_input_text
from advperc_ros.core.metrics.nds import CLASS_RANGE, in_range
from advperc_ros.core.occlusion import occlusion
from advperc_ros.core.perception_errors import PAPER_KINDS, ErrorSpace, PerceptionErrors, latency_source
from advperc_ros.exceptions import PEMError

NUM_FEATURES = 5
RANGE_SCALE = 50.0
MAX_LATENCY = 100  # frames a model's latency may be (a bound that keeps latency_source's loop short)
FIT_LATENCIES = ErrorSpace().max_latency  # a fit tries latencies 0..this, the error space's own bound
SCALE_FLOOR = 1e-3  # smallest velocity scale (m/s) and size std a fit gives: a log without such errors is no
# zero-width model
GHOST_SLOTS = ErrorSpace().ghosts  # sampled ghosts per frame at most (the attack's own bound)


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


@dataclass(frozen=True)
class ObjectFrames:
    """What the model scores, per counted object-frame (K rows, flat, of one or more sequences), and
    the frames' false positives: read off a perception output by `object_frames`, scored by
    `PEM.log_likelihoods`, fitted by `fit_object_frames`, so scoring and fitting read one thing."""

    phi: np.ndarray  # (K, NUM_FEATURES)
    detected: np.ndarray  # (K,) bool
    position: np.ndarray  # (K, 2) radial/tangential position error from the current truth, m
    dyaw: np.ndarray  # (K,) rad
    velocity: np.ndarray  # (K, 2) radial/tangential velocity error, m/s
    log_size: np.ndarray  # (K, 2) log of the length and width scale
    previous: np.ndarray  # (K,) row of the same agent's previous detected object-frame, -1 if none
    gap: np.ndarray  # (K,) frames back to it
    # latency -> (K, 5): what the agent's own motion over it adds to the errors (position radial and tangential,
    # yaw, velocity radial and tangential)
    lags: dict[int, np.ndarray]
    false_positives: np.ndarray  # (frames,) in-range detections no truth matched
    exposure: np.ndarray  # (frames,) counted object-frames per frame of the frame's sequence

    def lagged(self, latency: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(position, yaw, velocity) errors from the truth a detector `latency` frames late shows."""
        if latency == 0:
            return self.position, self.dyaw, self.velocity
        lag = self.lags[latency]
        return self.position - lag[:, :2], self.dyaw - lag[:, 2], self.velocity - lag[:, 3:]

    @classmethod
    def concatenate(cls, parts: list["ObjectFrames"]) -> "ObjectFrames":
        """One set of the object-frames of several sequences (each row's `previous` stays its own
        sequence's)."""
        offsets = np.cumsum([0] + [len(part.detected) for part in parts[:-1]])
        joined = {f.name: np.concatenate([getattr(part, f.name) for part in parts])
                  for f in fields(cls) if f.name not in ("previous", "lags")}
        previous = np.concatenate([np.where(p.previous >= 0, p.previous + o, -1) for p, o in zip(parts, offsets)])
        lags = {latency: np.concatenate([part.lags[latency] for part in parts]) for latency in parts[0].lags}
        return cls(previous=previous, lags=lags, **joined)


def _previous_detections(observed: np.ndarray, counted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per counted object-frame (in np.nonzero order): the row of the agent's latest earlier observed
    object-frame (-1 if none) and how many frames back it is."""
    frames = np.arange(observed.shape[0])[:, None]
    latest = np.maximum.accumulate(np.where(observed, frames, -1), axis=0)
    before = np.vstack([np.full((1, observed.shape[1]), -1), latest[:-1]])  # latest observed frame before k
    rows = np.full(observed.shape, -1)
    rows[counted] = np.arange(np.count_nonzero(counted))
    previous = np.where(before >= 0, rows[np.maximum(before, 0), np.arange(observed.shape[1])], -1)
    return previous[counted], (frames - before)[counted]


def _lag_offsets(truth: BoxSequence, latency: int, bearing: np.ndarray) -> np.ndarray:
    """(F, M, 5) as `ObjectFrames.lags`: the truth `latency` frames earlier (`latency_source`) minus the present one,
    positions and velocities turned radial/tangential to the present bearing."""
    source = latency_source(truth.valid, np.full(truth.shape, latency), slice(None))
    agents = np.arange(truth.shape[1])

    def back(values: np.ndarray) -> np.ndarray:
        return values[source, agents] - values

    position = to_radial(back(truth.x), back(truth.y), bearing)
    velocity = to_radial(back(truth.vx), back(truth.vy), bearing)
    return np.concatenate([position, wrap_angle(back(truth.yaw))[..., None], velocity], axis=-1)


def object_frames(truth: BoxSequence, errors: PerceptionErrors, ego_xy: np.ndarray, counted: np.ndarray,
                  phi: np.ndarray, latencies: tuple[int, ...] = (), tracked: bool = True,
                  reader: "PEM | None" = None) -> ObjectFrames:
    """The object-frames of one sequence: `errors` as `matched_errors` reads them (its ghost slots the
    in-range detections no truth matched), the lags of `latencies` (besides 0), `tracked` if a slot is
    one agent in every frame (else no agent has a previous detection, and no latency can be told).
    With a `reader`, only what that model scores is read and the rest left neutral (zero errors, no
    previous detection, no false positive): scoring the paper's parts costs what it did before the
    terms beyond them; without, everything is (a fit's)."""
    count = np.count_nonzero(counted)
    bearing = bearings(truth, ego_xy)
    rt = to_radial(errors.dx, errors.dy, bearing)[counted]
    velocity = log_size = np.zeros((count, 2))
    if errors.dvx is not None and errors.dvy is not None and (reader is None or reader.models_velocity):
        velocity = to_radial(errors.dvx, errors.dvy, bearing)[counted]
    if errors.length_scale is not None and errors.width_scale is not None and (reader is None or reader.models_size):
        with np.errstate(divide="ignore"):  # a zero-sized box has no size error to read: -inf, as its density says
            log_size = np.log(np.stack([errors.length_scale[counted], errors.width_scale[counted]], axis=-1))
    previous, gap = np.full(count, -1), np.ones(count, dtype=np.int64)
    if tracked and (reader is None or reader.position_ar != 0.0):
        previous, gap = _previous_detections(counted & ~errors.fn, counted)
    frames = truth.shape[0]
    false_positives = np.zeros(frames)
    if errors.ghost_on is not None and (reader is None or reader.false_positive_rate > 0.0):
        false_positives = errors.ghost_on.sum(axis=1).astype(float)
    return ObjectFrames(
        phi=phi[counted], detected=~errors.fn[counted], position=rt, dyaw=errors.dyaw[counted],
        velocity=velocity, log_size=log_size, previous=previous, gap=gap,
        lags={latency: _lag_offsets(truth, latency, bearing)[counted] for latency in latencies if latency},
        false_positives=false_positives, exposure=np.full(frames, count / frames),
    )


@dataclass(frozen=True)
class PEM:
    """A fitted perception error model: how likely a detector is to detect an object and how its
    position and yaw errors are distributed, given the object's features, and the terms beyond the
    paper's (module docstring), each off at its default. It tells typical errors from adversarial
    ones (the PEM log-likelihood objective, `check-typical`); frozen and saved as JSON so a report
    names the model it was scored with."""

    detection: tuple[float, ...]  # logit weights on phi
    position_loc: tuple[float, float]  # m, radial and tangential bias
    radial_log_scale: tuple[float, ...]  # weights on phi
    tangential_log_scale: tuple[float, ...]
    position_rho: float
    position_nu: float
    yaw_log_scale: tuple[float, ...]
    yaw_nu: float
    source: str  # where the numbers come from
    # beyond the paper; each default is the term's neutral value (a model saved before it loads so)
    false_positive_rate: float = 0.0  # ghosts per counted object-frame; 0: false positives not modelled
    flip_near: float = 0.0  # heading-flip probability at the ego,
    flip_far: float = 0.0  # and at RANGE_SCALE (linear between, constant beyond)
    velocity_radial_scale: float = 0.0  # m/s, Student-t scales of the velocity error; 0: not modelled
    velocity_tangential_scale: float = 0.0
    velocity_nu: float = 0.0  # its degrees of freedom (0 while the term is off)
    length_log_loc: float = 0.0  # normal of log(length scale): mean,
    length_log_std: float = 0.0  # and standard deviation; 0: sizes not modelled
    width_log_loc: float = 0.0
    width_log_std: float = 0.0
    latency: float = 0.0  # frames, a whole number: the truth the detector shows is this old
    position_ar: float = 0.0  # AR(1) coefficient of an agent's standardised position errors, frame to frame

    # ----- model -----
    def _linear(self, weights: tuple[float, ...], phi: np.ndarray) -> np.ndarray:
        return phi @ np.asarray(weights)

    def detection_probability(self, phi: np.ndarray) -> np.ndarray:
        return expit(self._linear(self.detection, phi))

    def flip_probability(self, phi: np.ndarray) -> np.ndarray:
        return self.flip_near + (self.flip_far - self.flip_near) * np.minimum(phi[..., 1], 1.0)

    @property
    def models_flips(self) -> bool:
        return self.flip_near > 0.0 or self.flip_far > 0.0

    @property
    def models_velocity(self) -> bool:
        return self.velocity_radial_scale > 0.0

    @property
    def models_size(self) -> bool:
        return self.length_log_std > 0.0

    @property
    def frames_late(self) -> int:
        return int(self.latency)

    @property
    def reads_beyond_the_paper(self) -> bool:
        """Whether scoring reads more of a perception output than the paper's errors: velocities,
        sizes or false positives (`matched_errors` reads them back only then)."""
        return self.models_velocity or self.models_size or self.false_positive_rate > 0.0

    def _position_scales(self, phi: np.ndarray) -> np.ndarray:
        return np.stack([np.exp(self._linear(self.radial_log_scale, phi)),
                         np.exp(self._linear(self.tangential_log_scale, phi))], axis=-1)

    def position_log_density(self, rt: np.ndarray, phi: np.ndarray, previous: np.ndarray, gap: np.ndarray):
        """log p(position error) per row: the marginal t, or with persistence the t given the row
        `previous` (rows of one flat set)."""
        if self.position_ar == 0.0:
            return _student_t_2d_logpdf(
                rt, np.asarray(self.position_loc), np.exp(self._linear(self.radial_log_scale, phi)),
                np.exp(self._linear(self.tangential_log_scale, phi)), self.position_rho, self.position_nu,
            )
        scales = self._position_scales(phi)
        persistence = _Persistence.of(rt, np.asarray(self.position_loc), scales, self.position_ar, previous, gap)
        return persistence.log_density(scales, self.position_rho, self.position_nu)

    def yaw_log_density(self, dyaw: np.ndarray, phi: np.ndarray):
        """log p(yaw error) per row: the t, or with flips its mixture with the t about pi."""
        scale = np.exp(self._linear(self.yaw_log_scale, phi))
        straight = _student_t_1d_logpdf(wrap_angle(dyaw), scale, self.yaw_nu)
        if not self.models_flips:
            return straight
        flipped = _student_t_1d_logpdf(wrap_angle(dyaw - np.pi), scale, self.yaw_nu)
        return _flip_mixture(straight, flipped, self.flip_probability(phi))

    def velocity_log_density(self, velocity: np.ndarray):
        return _student_t_2d_logpdf(velocity, np.zeros(2), self.velocity_radial_scale,
                                    self.velocity_tangential_scale, 0.0, self.velocity_nu)

    def size_log_density(self, log_size: np.ndarray):
        return (_normal_logpdf(log_size[:, 0], self.length_log_loc, self.length_log_std)
                + _normal_logpdf(log_size[:, 1], self.width_log_loc, self.width_log_std))

    def log_likelihoods(self, frames: ObjectFrames) -> np.ndarray:
        """Per object-frame log p(det | x) + [det] log p(errors | x), the errors taken from the truth
        the detector's latency shows."""
        logit = self._linear(self.detection, frames.phi)
        out = np.where(frames.detected, log_expit(logit), log_expit(-logit))
        position, dyaw, velocity = frames.lagged(self.frames_late)
        errors = (self.position_log_density(position, frames.phi, frames.previous, frames.gap)
                  + self.yaw_log_density(dyaw, frames.phi))
        if self.models_velocity:
            errors = errors + self.velocity_log_density(velocity)
        if self.models_size:
            errors = errors + self.size_log_density(frames.log_size)
        return out + np.where(frames.detected, errors, 0.0)

    def false_positive_log_likelihood(self, frames: ObjectFrames) -> float:
        """Sum over frames of log Poisson(false positives | rate x the frame's exposure)."""
        mean = self.false_positive_rate * frames.exposure
        count = frames.false_positives
        return float(np.sum(xlogy(count, mean) - mean - gammaln(count + 1.0)))

    def mean_log_likelihood(self, frames: ObjectFrames) -> float:
        """PEM LL: the object-frames' log-likelihoods and, when modelled, the frames' false positives',
        summed and divided by the object-frames."""
        ll = self.log_likelihoods(frames)
        total = ll.sum()
        if self.false_positive_rate > 0.0:
            total = total + self.false_positive_log_likelihood(frames)
        return float(total / ll.size)

    # ----- use on scenarios -----
    def score(
        self, truth: BoxSequence, errors: PerceptionErrors, ego_xy: np.ndarray, counted: np.ndarray,
        phi: np.ndarray | None = None,
    ) -> float:
        """Mean log-likelihood of the errors over the counted object-frames (present and in range);
        `errors` as `matched_errors` reads them back (ghost slots: in-range detections no truth
        matched); phi = features(truth, ego_xy) may be passed in when scoring many errors on one rollout."""
        if not counted.any():
            return float("nan")
        phi = features(truth, ego_xy) if phi is None else phi
        return self.mean_log_likelihood(object_frames(truth, errors, ego_xy, counted, phi, (self.frames_late,),
                                                      reader=self))

    def sample_features(self, phi: np.ndarray, rng: np.random.Generator):
        """(detected, radial/tangential position errors (..., 2), yaw errors) drawn for features phi,
        independently per row (the paper's parts)."""
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

    def _persist(self, rt: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """Independent position errors (frames x agents x 2) made persistent: their standardised values
        taken as innovations of the AR(1), frame after frame of each agent (present or not, so that a
        gap of m frames decays as a^m, as scored)."""
        loc, scales = np.asarray(self.position_loc), self._position_scales(phi)
        z = (rt - loc) / scales
        a = self.position_ar
        for k in range(1, len(z)):
            z[k] = a * z[k - 1] + math.sqrt(1.0 - a * a) * z[k]
        return loc + scales * z

    def sample(self, truth: BoxSequence, ego_xy: np.ndarray, rng: np.random.Generator) -> PerceptionErrors:
        """An error tensor drawn from the model for the given truth and ego positions, with the arrays
        of the extended kinds the model has terms for (their draws follow the paper's, so a model
        without them draws today's tensor)."""
        phi = features(truth, ego_xy)
        detected, rt, dyaw = self.sample_features(phi, rng)
        if self.position_ar != 0.0:
            rt = self._persist(rt, phi)
        bearing = bearings(truth, ego_xy)
        dx, dy = to_world(rt, bearing)
        kinds: dict[str, np.ndarray] = {}
        shape = truth.shape
        if self.models_velocity:  # the bivariate t: a normal pair over one sqrt(chi2 / nu)
            g = rng.standard_normal((*shape, 2))
            w = np.sqrt(rng.chisquare(self.velocity_nu, shape) / self.velocity_nu)[..., None]
            scales = np.array([self.velocity_radial_scale, self.velocity_tangential_scale])
            kinds["dvx"], kinds["dvy"] = to_world(scales * g / w, bearing)
        if self.models_size:
            kinds["length_scale"] = np.exp(rng.normal(self.length_log_loc, self.length_log_std, shape))
            kinds["width_scale"] = np.exp(rng.normal(self.width_log_loc, self.width_log_std, shape))
        if self.models_flips:
            kinds["flip"] = rng.random(shape) < self.flip_probability(phi)
        if self.frames_late:
            kinds["latency"] = np.full(shape, self.frames_late, dtype=np.int64)
        if self.false_positive_rate > 0.0:
            kinds.update(self._ghosts(truth, ego_xy, rng))
        return PerceptionErrors(dx=dx, dy=dy, dyaw=dyaw, fn=~detected, **kinds)

    def _ghosts(self, truth: BoxSequence, ego_xy: np.ndarray, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """Ghost detections: per frame a Poisson number with the scored mean (at most GHOST_SLOTS, the
        attack's bound), each uniform over the disc in range around the ego, its heading uniform, moving
        along it at the speed of a random present agent-frame: as the cars of this scene move."""
        frames = truth.shape[0]
        mean = self.false_positive_rate * np.count_nonzero(in_range(truth, ego_xy)) / frames
        count = np.minimum(rng.poisson(mean, frames), GHOST_SLOTS)
        shape = (frames, GHOST_SLOTS)
        radius = CLASS_RANGE * np.sqrt(rng.random(shape))
        bearing = rng.uniform(-np.pi, np.pi, shape)
        yaw = rng.uniform(-np.pi, np.pi, shape)
        speeds = np.hypot(truth.vx, truth.vy)[truth.valid]
        speed = rng.choice(speeds, shape) if speeds.size else np.zeros(shape)
        return {
            "ghost_on": np.arange(GHOST_SLOTS) < count[:, None],
            "ghost_x": ego_xy[:, :1] + radius * np.cos(bearing), "ghost_y": ego_xy[:, 1:2] + radius * np.sin(bearing),
            "ghost_yaw": yaw, "ghost_vx": speed * np.cos(yaw), "ghost_vy": speed * np.sin(yaw),
        }

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
        Every field is checked here, so a wrong model fails on loading, not inside a rollout. The
        fields of the terms beyond the paper may be absent (the term is off)."""
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
        values = {name: _checked(data.get(name), name, source) for name in names if name in data or name in _REQUIRED}
        model = cls(**values)
        _check_terms(model, source)
        return model


@dataclass(frozen=True)
class _Field:
    """What a model field holds: `count` numbers (None: a single one) within (low, high), `low` itself
    allowed if `closed`, a whole number if `whole`."""

    count: int | None
    low: float = -math.inf
    high: float = math.inf
    closed: bool = False
    whole: bool = False

    def admits(self, number: float | None) -> bool:
        if number is None or not (self.low < number < self.high or (self.closed and number == self.low)):
            return False
        return not self.whole or number == int(number)

    def describe(self) -> str:
        if self.count is not None:
            return f"a list of {self.count} numbers, finite"
        what = "a whole number" if self.whole else "a number"
        return f"{what} in {'[' if self.closed else '('}{self.low}, {self.high})"


_FIELDS = {
    "detection": _Field(NUM_FEATURES),
    "position_loc": _Field(2),
    "radial_log_scale": _Field(NUM_FEATURES),
    "tangential_log_scale": _Field(NUM_FEATURES),
    "position_rho": _Field(None, -1.0, 1.0),
    "position_nu": _Field(None, 0.0),
    "yaw_log_scale": _Field(NUM_FEATURES),
    "yaw_nu": _Field(None, 0.0),
    "false_positive_rate": _Field(None, 0.0, 1000.0, closed=True),  # beyond, no detector (and no Poisson draw)
    "flip_near": _Field(None, 0.0, 1.0, closed=True),
    "flip_far": _Field(None, 0.0, 1.0, closed=True),
    "velocity_radial_scale": _Field(None, 0.0, closed=True),
    "velocity_tangential_scale": _Field(None, 0.0, closed=True),
    "velocity_nu": _Field(None, 0.0, closed=True),
    "length_log_loc": _Field(None),
    "length_log_std": _Field(None, 0.0, closed=True),
    "width_log_loc": _Field(None),
    "width_log_std": _Field(None, 0.0, closed=True),
    "latency": _Field(None, 0.0, MAX_LATENCY + 1.0, closed=True, whole=True),
    "position_ar": _Field(None, -1.0, 1.0),
}
_REQUIRED = ("detection", "position_loc", "radial_log_scale", "tangential_log_scale", "position_rho", "position_nu",
             "yaw_log_scale", "yaw_nu", "source")  # the paper's parts; the others are optional terms
# terms whose fields are on or off together: (field that switches it, fields that must be above 0 with it)
_TERMS = {"velocity": ("velocity_radial_scale", ("velocity_tangential_scale", "velocity_nu")),
          "size": ("length_log_std", ("width_log_std",))}


def _checked(value, name: str, source: str):
    """A field's JSON value as the model holds it, or a PEMError saying what the field must be."""
    if name == "source":
        if not isinstance(value, str):
            raise PEMError(f"{source}: field 'source' must be a string")
        return value
    spec = _FIELDS[name]
    items = [value] if spec.count is None else value if isinstance(value, list) and len(value) == spec.count else [None]
    numbers = [_number(item) for item in items]
    if not all(spec.admits(number) for number in numbers):
        shown = (f"a list of {len(value)}" if isinstance(value, list) else "an object" if isinstance(value, dict)
                 else f"{value!r:.60}")
        raise PEMError(f"{source}: field '{name}' must be {spec.describe()}, not {shown}")
    return numbers[0] if spec.count is None else tuple(numbers)


def _check_terms(model: PEM, source: str) -> None:
    """A term is on or off as a whole: its other scales (and degrees of freedom) are above 0 exactly
    when its switch is."""
    for term, (switch, others) in _TERMS.items():
        on = getattr(model, switch) > 0.0
        for name in others:
            if (getattr(model, name) > 0.0) != on:
                raise PEMError(f"{source}: field '{name}' must be {'above 0' if on else '0'} when '{switch}' is "
                               f"{'above 0' if on else '0'} (the {term} term is on or off as a whole)")


def _number(value) -> float | None:
    """A JSON number as a float; None for anything else (booleans, strings, ints beyond a float)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        return float(value)
    except OverflowError:
        return None


@lru_cache(maxsize=2)
def _bundled(name: str) -> PEM:
    return PEM.from_json(resources.files("advperc_ros").joinpath(f"data/{name}").read_text(), name)


def default_pem(kinds: tuple[str, ...] = PAPER_KINDS) -> PEM:
    """The shipped reference model for errors of `kinds`: the paper's kinds keep the hand-specified
    model every published PEM LL of them was scored with (default_pem.json), so none moves; any kind
    beyond them gets the model calibrated on a real detector's published statistics, with every term
    (default_pem_extended.json). Each file's `source` says what it is."""
    return _bundled("default_pem.json" if set(kinds) <= set(PAPER_KINDS) else "default_pem_extended.json")


# ----- fitting -----
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
