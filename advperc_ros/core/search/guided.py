"""Beyond the paper: a search that spends every rollout on the candidate most likely to pay.

Algorithm 2 rolls out one random improving proposal per step, and none when no proposal improves,
so its budget is left unspent. Scoring a candidate needs no rollout, so each round here draws many
candidates from the best attack so far, scores them all exactly on its rollout, and rolls out the
`batch` with the largest expected gain: (metric - best) x P(still collides). P comes from a
logistic model of the verdict against the move and the candidate's gain, fitted to this search's
own rollouts, so it learns which moves and how bold a step this planner's failure boundary
tolerates. Moves: the paper's proposal (a dropped segment detected again, offset), a lateral push
that hides a car from a corridor at the least NDS cost, and two moves towards zero along the
boundary: shrinking the offsets of a segment, and perceiving the edge frames of an attacked run
perfectly again. A round's rollouts are independent, so a backend may run them at once; the batch
size is a param, so the attack does not depend on how many workers ran it.
"""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.errors import PerceptionErrors
from advperc_ros.core.metrics.nds import DIST_THRESHOLDS
from advperc_ros.core.search.problem import AttackProblem, Evaluation, Phase
from advperc_ros.core.search.random_search import RandomSearchConfig, propose
from advperc_ros.core.search.refine import dropped_runs

# m: a push just inside the loosest match threshold: still a true positive, so it costs no more NDS
# than a 2 m offset (both miss the tighter thresholds) and it is no drop, yet it moves a car furthest
PUSH = 0.95 * max(DIST_THRESHOLDS)


@dataclass(frozen=True)
class GuidedConfig:
    candidates: int = 400  # scored per round
    batch: int = 2  # rolled out per round
    random: RandomSearchConfig = RandomSearchConfig()  # the paper's proposal: max offset, yaw noise


def attacked_runs(errors: PerceptionErrors, frames: int) -> list[tuple[int, int, int]]:
    """(slot, first, last) of every run of attacked (dropped or displaced) frames."""
    return dropped_runs((errors.fn | (errors.dx != 0) | (errors.dy != 0))[:frames])


def shrink(errors: PerceptionErrors, frames: int, rng: np.random.Generator) -> PerceptionErrors | None:
    """Scale the offsets of a sub-run of displaced frames towards zero by a U(0, 1) factor."""
    displaced = [run for run in attacked_runs(errors, frames) if not errors.fn[run[1] : run[2] + 1, run[0]].all()]
    if not displaced:
        return None
    j, first, last = displaced[rng.integers(len(displaced))]
    a, b = np.sort(rng.integers(first, last + 1, size=2))
    out = errors.copy()
    factor = rng.uniform(0.0, 1.0)
    for array in (out.dx, out.dy, out.dyaw):
        array[a : b + 1, j] *= factor
    return out


def restore(errors: PerceptionErrors, frames: int, rng: np.random.Generator) -> PerceptionErrors | None:
    """Perceive the first or last k frames of an attacked run perfectly again (k up to half the run)."""
    runs = attacked_runs(errors, frames)
    if not runs:
        return None
    j, first, last = runs[rng.integers(len(runs))]
    k = int(rng.integers(1, max(1, (last - first + 1) // 2) + 1))
    a, b = (first, first + k - 1) if rng.integers(2) else (last - k + 1, last)
    out = errors.copy()
    out.fn[a : b + 1, j] = False
    out.dx[a : b + 1, j] = out.dy[a : b + 1, j] = out.dyaw[a : b + 1, j] = 0.0
    return out


def push(errors: PerceptionErrors, frames: int, rng: np.random.Generator, yaw: np.ndarray) -> PerceptionErrors | None:
    """Perceive an attacked run (half the time a uniform sub-run of it) PUSH metres to one side of the
    car's heading: out of a corridor it occupied, at no more cost than a smaller offset."""
    runs = attacked_runs(errors, frames)
    if not runs:
        return None
    j, a, b = runs[rng.integers(len(runs))]
    if rng.integers(2):
        a, b = np.sort(rng.integers(a, b + 1, size=2))
    side = PUSH if rng.integers(2) else -PUSH
    out = errors.copy()
    out.fn[a : b + 1, j] = False
    out.dx[a : b + 1, j] = -np.sin(yaw[a : b + 1, j]) * side
    out.dy[a : b + 1, j] = np.cos(yaw[a : b + 1, j]) * side
    out.dyaw[a : b + 1, j] = 0.0
    return out


MOVES = ("flip", "push", "shrink", "restore")


def candidate(errors: PerceptionErrors, frames: int, rng: np.random.Generator, cfg: GuidedConfig, yaw: np.ndarray):
    """(move index, candidate) by a move chosen uniformly; the candidate is None when that move has
    nothing to act on (flip: the paper's proposal, which needs a dropped frame)."""
    move = int(rng.integers(len(MOVES)))
    if move == 0:
        return move, propose(errors, frames, rng, cfg.random)
    if move == 1:
        return move, push(errors, frames, rng, yaw)
    return move, (shrink if move == 2 else restore)(errors, frames, rng)


def _key(errors: PerceptionErrors) -> bytes:
    return b"".join(np.ascontiguousarray(a).tobytes() for a in (errors.dx, errors.dy, errors.dyaw, errors.fn))


def _features(moves: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """One intercept per move and the gain (as a fraction of the round's largest)."""
    return np.column_stack([np.eye(len(MOVES))[moves], gains])


def fit_still_fails(moves: np.ndarray, gains: np.ndarray, failed: np.ndarray) -> np.ndarray:
    """Weights of P(collides) = sigmoid(features . w), by maximum likelihood with a weak prior for
    every move that no gain keeps the verdict and the round's largest gain loses it."""
    prior = np.arange(len(MOVES))
    x = _features(np.concatenate([moves, prior, prior]).astype(int),
                  np.concatenate([gains, np.zeros(len(MOVES)), np.ones(len(MOVES))]))
    y = np.concatenate([failed.astype(float), np.ones(len(MOVES)), np.zeros(len(MOVES))])
    w = np.zeros(x.shape[1])
    for _ in range(100):  # Newton on an L2-regularised logistic regression
        p = 1.0 / (1.0 + np.exp(-x @ w))
        grad = x.T @ (y - p) - 0.1 * w
        hess = -(x.T * (p * (1.0 - p))) @ x - 0.1 * np.eye(x.shape[1])
        delta = np.linalg.solve(hess, grad)
        w -= delta
        if np.abs(delta).max() < 1e-9:
            break
    return w


def pick_batch(gain: np.ndarray, chance: np.ndarray, size: int) -> list[int]:
    """Greedily, the candidates that most raise the expected best gain of the batch, each collision
    taken as independent: the first is the largest gain x chance, the next ones pay where the chosen
    ones fail (a safer candidate beside a bold one)."""
    chosen: list[int] = []
    for _ in range(size):
        value = np.full(gain.size, -np.inf)
        for i in range(gain.size):
            if i in chosen:
                continue
            batch = sorted(chosen + [i], key=lambda k: -gain[k])
            miss, total = 1.0, 0.0
            for k in batch:  # the best gain realised is the largest among those that collide
                total += miss * chance[k] * gain[k]
                miss *= 1.0 - chance[k]
            value[i] = total
        chosen.append(int(np.argmax(value)))
    return chosen


def guided_search(problem: AttackProblem, rng: np.random.Generator, cfg: GuidedConfig, budget: int) -> Evaluation:
    """Rounds from the problem's best attack until it has logged `budget` rollouts; the best attack."""
    moves: list[int] = []  # of every conclusive guided rollout: its move,
    gains: list[float] = []  # its scored gain over its parent as a fraction of its round's largest,
    failed: list[bool] = []  # and whether it still collided
    tried: set[bytes] = set()
    yaw = problem.scenario.agents.yaw
    while len(problem.log) < budget:
        parent = problem.best
        frames = parent.rollout.num_frames
        pool = {}
        for _ in range(cfg.candidates):  # distinct candidates never rolled out, in the order drawn
            move, c = candidate(parent.errors, frames, rng, cfg, yaw)
            if c is not None and _key(c) not in tried:
                pool.setdefault(_key(c), (move, c))
        scored = [(problem.metric(c, parent.rollout) - parent.metric, move, c) for move, c in pool.values()]
        scored = [entry for entry in scored if entry[0] > 0]
        if not scored:
            break  # nothing scores above the best attack: no rollout can improve it
        gain = np.array([g for g, _, _ in scored])
        relative = gain / gain.max()
        move = np.array([m for _, m, _ in scored])
        w = fit_still_fails(np.array(moves, dtype=int), np.array(gains), np.array(failed, dtype=bool))
        chance = 1.0 / (1.0 + np.exp(-_features(move, relative) @ w))
        chosen = pick_batch(gain, chance, min(cfg.batch, budget - len(problem.log)))
        batch = [scored[i][2] for i in chosen]
        tried.update(_key(c) for c in batch)
        trials = problem.evaluate_many([(c, Phase.GUIDED, -1) for c in batch])
        for i, trial in zip(chosen, trials):
            if not trial.rollout.inconclusive:
                moves.append(int(move[i]))
                gains.append(float(relative[i]))
                failed.append(trial.adversarial)
    return problem.best
