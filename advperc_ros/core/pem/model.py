"""The perception error model itself: its parameters, its log-likelihood of a perception output, its
draws of error tensors, and its JSON form (the checks of each field are `schema`'s)."""

import json
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
from scipy.special import expit, gammaln, log_expit, xlogy

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.geometry import wrap_angle
from advperc_ros.core.inputs import read_input_text
from advperc_ros.core.pem.densities import (
    _flip_mixture,
    _Persistence,
    _student_t_1d_logpdf,
    _student_t_2d_logpdf,
    bearings,
    features,
    to_world,
)
from advperc_ros.core.pem.frames import ObjectFrames, object_frames
from advperc_ros.core.pem.schema import REQUIRED, check_terms, checked
from advperc_ros.core.pem.terms import TERMS, Draw
from advperc_ros.core.perception_errors import PerceptionErrors, kind_named
from advperc_ros.exceptions import PEMError


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
        """Whether scoring reads more of a perception output than the paper's errors: whether a term is
        on whose kind the metrics read back (velocities, sizes, false positives: `matched_errors`
        reads them back only then)."""
        return any(term.on(self) and kind_named(term.kind).read_back is not None for term in TERMS)

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

    def log_likelihoods(self, frames: ObjectFrames) -> np.ndarray:
        """Per object-frame log p(det | x) + [det] log p(errors | x), the errors taken from the truth
        the detector's latency shows."""
        logit = self._linear(self.detection, frames.phi)
        out = np.where(frames.detected, log_expit(logit), log_expit(-logit))
        position, dyaw, velocity = frames.lagged(self.frames_late)
        errors = (self.position_log_density(position, frames.phi, frames.previous, frames.gap)
                  + self.yaw_log_density(dyaw, frames.phi))
        for term in TERMS:
            if term.log_density is not None and term.on(self):
                errors = errors + term.log_density(self, frames, velocity)
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
        draw = Draw(truth, ego_xy, phi, bearing)
        for term in TERMS:  # in the kinds' order, each drawing after the paper's parts and the terms before it
            if term.on(self):
                kinds.update(term.sample(self, draw, rng))
        return PerceptionErrors.of(dx=dx, dy=dy, dyaw=dyaw, fn=~detected, **kinds)

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
        values = {name: checked(data.get(name), name, source) for name in names if name in data or name in REQUIRED}
        model = cls(**values)
        check_terms(model, source)
        return model
