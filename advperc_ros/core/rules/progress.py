"""Rule `progress`: the ego's progress along its route against the ground truth's rollout.

As nuPlan's ego_progress_along_expert_route with ego_is_making_progress: the ratio of the ego's
progress along the route to the expert's (here the ground truth's rollout of the same scenario, the
stack on error-free perception), each taken as at least score_progress_threshold, 2 m, so that a
ground truth that barely moves scores 1 (low_level/ego_progress_along_expert_route_statistics.yaml),
capped at 1, and 0 when the ego went back more than that threshold; the drive makes progress when
the ratio is at least min_progress_threshold, 0.2 (high_level/ego_is_making_progress_statistics.yaml).
nuPlan scores the whole drive; here the ratio is taken at every frame over the frames so far, so a
drive that stops for nothing is caught at the frame its ratio falls under the bound, and the
last frame's ratio is nuPlan's. r = ratio - min_progress_threshold.
"""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.parameters import Bounds, parameter
from advperc_ros.core.rules.base import ParameterisedRule
from advperc_ros.core.rules.inputs import RuleInputs, held


@dataclass(frozen=True)
class ProgressParameters:
    """Least progress, as a fraction of the ground truth's, and the distance below which both count alike."""

    min_progress_ratio: float = parameter(
        0.2, "nuPlan ego_is_making_progress_statistics.yaml: min_progress_threshold (fraction)",
        Bounds(low=0.0, high=1.0))
    score_progress_threshold: float = parameter(
        2.0, "nuPlan ego_progress_along_expert_route_statistics.yaml: score_progress_threshold (m)",
        Bounds(low=0.0, high=10_000.0))


class Progress(ParameterisedRule):
    """Too little progress: a planner that stops or crawls for nothing passes every safety rule."""

    name = "progress"
    meaning = "the ego's progress along the route as a fraction of the ground truth's, minus nuPlan's 0.2"
    unit = "fraction of the ground truth's progress"
    needs_reference = True
    Parameters = ProgressParameters
    parameters: ProgressParameters

    def per_frame(self, inputs: RuleInputs, reference: RuleInputs | None = None) -> np.ndarray:
        assert reference is not None  # base.evaluate checks it
        p = self.parameters
        ego = route_progress(inputs)
        truth = held(route_progress(reference), ego.size)
        floor = p.score_progress_threshold
        ratio = np.minimum(1.0, np.maximum(ego, floor) / np.maximum(truth, floor))
        return np.where(ego < -floor, 0.0, ratio) - p.min_progress_ratio


def route_progress(inputs: RuleInputs) -> np.ndarray:
    """(K,) m along the route from the first frame's position to each frame's."""
    station, _ = inputs.route.project(inputs.ego[:, :2])
    return station - station[0]
