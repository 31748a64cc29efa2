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

The package by concern: `densities` (features and distributions), `frames` (what is scored and
fitted), `model` (the model), `schema` (what its JSON fields may hold), `defaults` (the bundled
models) and `fit` (maximum likelihood).
"""

from advperc_ros.core.pem.defaults import default_pem
from advperc_ros.core.pem.densities import NUM_FEATURES, RANGE_SCALE, bearings, features, to_radial, to_world
from advperc_ros.core.pem.fit import FIT_LATENCIES, SCALE_FLOOR, fit, fit_object_frames
from advperc_ros.core.pem.frames import ObjectFrames, object_frames
from advperc_ros.core.pem.model import PEM
from advperc_ros.core.pem.terms import GHOST_SLOTS, MAX_LATENCY, TERMS, Term
from advperc_ros.exceptions import PEMError

__all__ = [
    "FIT_LATENCIES", "GHOST_SLOTS", "MAX_LATENCY", "NUM_FEATURES", "PEM", "RANGE_SCALE", "SCALE_FLOOR", "TERMS",
    "ObjectFrames", "PEMError", "Term", "bearings", "default_pem", "features", "fit", "fit_object_frames",
    "object_frames", "to_radial", "to_world",
]
