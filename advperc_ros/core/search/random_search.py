"""Algorithm 2 of the paper: random search that trades false negatives for small errors.

Each step draws proposals that flip a segment of a dropped track back to detected, with one
position offset of uniform direction and U(0, max_offset) magnitude for the segment and per-frame
yaw noise N(0, yaw_std). Proposals are scored on the previous rollout's ground truth; one
improving proposal, chosen at random, is rolled out and kept if the rule is still broken.
"""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.search.problem import AttackProblem, Evaluation, Phase, PhaseLabel

LABEL = PhaseLabel("random search", "tab:cyan", "--")  # as the paper's method shows it


@dataclass(frozen=True)
class RandomSearchConfig:
    """The paper's Algorithm 2: its steps, proposals per step, and how far a proposal displaces a
    re-detected segment; the guided search and the approach phase draw their proposals with it too."""

    steps: int = 40
    proposals: int = 100
    max_offset: float = 5.0  # m
    yaw_std: float = 0.1  # rad


def pick_segment(mask: np.ndarray, rng: np.random.Generator) -> tuple[int, np.ndarray] | None:
    """(slot, frames): a slot uniform among those with a frame in `mask` (frames x slots), and its
    frames in `mask` between a start and an end uniform over its span; None when `mask` is empty."""
    agents = np.flatnonzero(mask.any(axis=0))
    if agents.size == 0:
        return None
    j = int(agents[rng.integers(agents.size)])
    span = np.flatnonzero(mask[:, j])
    a, b = np.sort(rng.integers(span[0], span[-1] + 1, size=2))
    return j, span[(span >= a) & (span <= b)]


def propose(
    errors: PerceptionErrors, frames: int, rng: np.random.Generator, cfg: RandomSearchConfig,
    where: np.ndarray | None = None,
) -> PerceptionErrors | None:
    """p(e | e_prev): flip a segment of a dropped track within the first `frames` frames; its start
    and end are uniform over the agent's dropped span. `where` ((frames, slots)): the object-frames
    that may be shown displaced instead of the dropped ones (the approach phase shows cars that
    were seen, displaced)."""
    picked = pick_segment(errors.fn[:frames] if where is None else where[:frames], rng)
    if picked is None:
        return None
    j, flip = picked
    direction = rng.uniform(0.0, 2.0 * np.pi)
    magnitude = rng.uniform(0.0, cfg.max_offset)
    out = errors.copy()
    out.fn[flip, j] = False
    out.dx[flip, j] = magnitude * np.cos(direction)
    out.dy[flip, j] = magnitude * np.sin(direction)
    out.dyaw[flip, j] = rng.normal(0.0, cfg.yaw_std, size=flip.size)
    return out


def random_search(
    problem: AttackProblem, initial: Evaluation, rng: np.random.Generator, cfg: RandomSearchConfig = RandomSearchConfig()
) -> Evaluation:
    """The last accepted evaluation (the best adversarial one is tracked by the problem)."""
    current = initial
    for _ in range(cfg.steps):
        alpha = current.metric
        frames = current.rollout.num_frames
        proposals = [propose(current.errors, frames, rng, cfg) for _ in range(cfg.proposals)]
        improving = [p for p in proposals if p is not None and problem.metric(p, current.rollout) > alpha]
        if not improving:
            continue
        trial = problem.evaluate(improving[rng.integers(len(improving))], Phase.RANDOM)
        if trial.adversarial:
            current = trial
    return current
