"""Beyond the paper: a search that spends every rollout on the candidate most likely to pay.

Algorithm 2 rolls out one random improving proposal per step, and none when no proposal improves,
so its budget is left unspent. Scoring a candidate needs no rollout, so each round here draws many
candidates from the best attack so far, scores them all exactly on its rollout, and rolls out the
`batch` with the largest expected gain: (metric - best) x P(still collides). P comes from a
logistic model of the verdict against the move and the candidate's gain, fitted to this search's
own rollouts, so it learns which moves and how bold a step this planner's failure boundary
tolerates. Moves: the paper's proposal (a dropped segment detected again, offset); pushes, which
perceive a run of a car displaced ahead of, behind or beside itself by just under a match threshold
(within a threshold's band every offset costs the same average precision, so the largest moves the
car furthest for that cost: sideways out of a corridor, or ahead or behind so that it seems to
arrive earlier or later); and two moves towards zero along the boundary: shrinking the offsets of
a segment, and perceiving the edge frames of an attacked run perfectly again. Each push axis is a
move of its own, so the model learns which way this planner's decision turns. When two rollouts
of a round collide, the next round also tries the best with the other's change merged in. A trust
region bounds the gain of a batch's second candidate: shrunk by 1/sqrt(2) after a round that lost
every collision, doubled after one that raised the best (so it holds where a third of the steps
keep the collision), so where the failure boundary hugs the best attack the steps come down to the
few that keep it (as the paper's uniform proposals sometimes do
by chance), but not below what re-rolling alone changes a metric by; the first candidate stays the
model's choice. A round's rollouts are independent, so a backend may run them at once; the batch
size is a param, so the attack does not depend on how many workers ran it. With error kinds beyond
the paper's on (`errors.kinds`), each kind's moves (its `ErrorKind.moves`) join the draw, and the
collision model learns them as it learns the paper's.
"""

from collections.abc import Sequence
from typing import ClassVar

import numpy as np

from advperc_ros.core.metrics.nds import DIST_THRESHOLDS
from advperc_ros.core.perception_errors import ErrorSpace, MoveContext, PerceptionErrors, registry
from advperc_ros.core.perception_errors.runs import attacked_runs, run_edge
from advperc_ros.core.rollout import true_agents
from advperc_ros.core.search import refine
from advperc_ros.core.search.config import GuidedConfig, SearchConfig, after_failure_bound
from advperc_ros.core.search.problem import AttackProblem, Evaluation, LogRow, Phase, PhaseLabel
from advperc_ros.core.search.random_search import propose
from advperc_ros.core.search.refine import refine_drops

# m: pushes just inside each match threshold (a true positive at that threshold and every looser one)
PUSHES = 0.95 * np.asarray(DIST_THRESHOLDS, dtype=float)


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
    a, b = run_edge(first, last, rng)
    out = errors.copy()
    out.perceive_perfectly(a, b, j)
    return out


# the paper's kinds' moves; the extended kinds' (`ErrorKind.moves`) go before `merge`, which is never drawn
MOVES = ("flip", "push_ahead", "push_behind", "push_left", "push_right", "shrink", "restore", "merge")


def moves_of(kinds: tuple[str, ...]) -> tuple[str, ...]:
    """The guided search's moves when `kinds` are on: the paper's, then each extended kind's, then merge."""
    extended = tuple(name for kind in kinds for name, _ in registry.kind_named(kind).moves)
    return (*MOVES[:-1], *extended, MOVES[-1])


AXES = ((1, 0), (-1, 0), (0, 1), (0, -1))  # (along, beside) the car's heading of each push move, in order


def displacement(yaw: np.ndarray, axis: int, distance: float) -> tuple[np.ndarray, np.ndarray]:
    """(dx, dy) in the map of a car heading `yaw` shown `distance` along AXES[axis] of itself."""
    along, side = np.array(AXES[axis], dtype=float) * distance
    cos, sin = np.cos(yaw), np.sin(yaw)
    return cos * along - sin * side, sin * along + cos * side


def push(
    errors: PerceptionErrors, frames: int, rng: np.random.Generator, yaw: np.ndarray, axis: int
) -> PerceptionErrors | None:
    """Perceive an attacked run (half the time a uniform sub-run of it) displaced along AXES[axis] of
    the car by just under one of the match thresholds."""
    runs = attacked_runs(errors, frames)
    if not runs:
        return None
    j, a, b = runs[rng.integers(len(runs))]
    if rng.integers(2):
        a, b = np.sort(rng.integers(a, b + 1, size=2))
    distance = PUSHES[rng.integers(PUSHES.size)]
    out = errors.copy()
    out.fn[a : b + 1, j] = False
    out.dx[a : b + 1, j], out.dy[a : b + 1, j] = displacement(yaw[a : b + 1, j], axis, distance)
    out.dyaw[a : b + 1, j] = 0.0
    return out


def candidate(errors: PerceptionErrors, frames: int, rng: np.random.Generator, cfg: GuidedConfig, yaw: np.ndarray,
              moves: tuple[str, ...] = MOVES, context: MoveContext | None = None):
    """(move index, candidate) by a move of `moves` chosen uniformly; the candidate is None when that
    move has nothing to act on (flip: the paper's proposal, which needs a dropped frame). Merges are
    not drawn: they come from a round's other collisions. The extended kinds' moves need `context`."""
    move = int(rng.integers(len(moves) - 1))
    if move == 0:
        return move, propose(errors, frames, rng, cfg.random)
    if 1 <= move <= 4:
        return move, push(errors, frames, rng, yaw, move - 1)
    if move <= 6:
        return move, (shrink if move == 5 else restore)(errors, frames, rng)
    if context is None:
        raise ValueError(f"move '{moves[move]}' needs the move context")
    extended = {name: made for kind in registry.KINDS for name, made in kind.moves}
    return move, extended[moves[move]](errors, frames, rng, context)


def _aligned(*tensors: PerceptionErrors) -> list[PerceptionErrors]:
    """The tensors with the arrays of each other's kinds (neutral where one had none), ghost slots alike."""
    ghosts = max(errors.ghost_slots for errors in tensors)
    kinds = {kind for errors in tensors for kind in errors.kinds}
    aligned = []
    for errors in tensors:
        for kind in sorted(kinds):
            errors = errors.with_kind(kind, ghosts)
        aligned.append(errors)
    return aligned


def _agent_arrays(errors: PerceptionErrors) -> dict[str, np.ndarray]:
    specs = registry.array_specs()
    return {name: array for name, array in errors.arrays().items() if not specs[name].per_ghost}


def _ghost_arrays(errors: PerceptionErrors) -> dict[str, np.ndarray]:
    specs = registry.array_specs()
    return {name: array for name, array in errors.arrays().items() if specs[name].per_ghost}


def changed_cells(errors: PerceptionErrors, parent: PerceptionErrors) -> np.ndarray:
    """(frames x slots) mask of the object-frames whose errors differ from the parent's."""
    errors, parent = _aligned(errors, parent)
    mine, theirs = _agent_arrays(errors), _agent_arrays(parent)
    return np.logical_or.reduce([mine[name] != theirs[name] for name in mine])


def _changed_ghosts(errors: PerceptionErrors, parent: PerceptionErrors) -> np.ndarray:
    """(frames x ghost slots) mask of the ghost cells that differ from the parent's (both with ghosts)."""
    mine, theirs = _ghost_arrays(errors), _ghost_arrays(parent)
    return np.logical_or.reduce([mine[name] != theirs[name] for name in mine])


def merge(best: PerceptionErrors, sibling: PerceptionErrors, parent: PerceptionErrors) -> PerceptionErrors | None:
    """The best attack with what a sibling (another collision of the round that made it) changed in
    their parent: both changes kept the collision alone, so together they are a likely larger step."""
    best, sibling, parent = _aligned(best, sibling, parent)
    changed = changed_cells(sibling, parent)
    ghosts = _changed_ghosts(sibling, parent) if _ghost_arrays(sibling) else np.zeros((0, 0), dtype=bool)
    if not changed.any() and not ghosts.any():
        return None
    out = best.copy()
    theirs, specs = sibling.arrays(), registry.array_specs()
    for name, array in out.arrays().items():
        cells = ghosts if specs[name].per_ghost else changed
        array[cells] = theirs[name][cells]
    return out


def _key(errors: PerceptionErrors) -> bytes:
    return b"".join(name.encode() + np.ascontiguousarray(a).tobytes() for name, a in errors.arrays().items())


def wrongness(errors: PerceptionErrors, space: ErrorSpace = ErrorSpace()) -> np.ndarray:
    """(frames x slots) how wrong each object-frame is shown, in [0, 1]: the largest share of its bound
    of any kind it has (`ErrorKind.wrongness`: an offset over the loosest match threshold, a drop
    counting as 1, a turned car as 1, as its heading is as wrong as it can be)."""
    out: np.ndarray | None = None
    for kind in registry.KINDS:
        if kind.wrongness is not None and kind.present(errors):
            share = kind.wrongness(errors, space)
            out = share if out is None else np.maximum(out, share)
    assert out is not None  # the paper's kinds have theirs
    return out


def shown(c: PerceptionErrors, parent: PerceptionErrors, before: np.ndarray,
          space: ErrorSpace = ErrorSpace()) -> tuple[float, float]:
    """What the collision model reads of a candidate besides its move and gain (`before`: the
    parent's wrongness, the same for a whole round):
    - falsity, how wrong it shows what it changes in its parent: the mean wrongness of its changed
      object-frames (a car shown 3.8 m aside fools a corridor where one shown 1.9 m aside does not);
    - the share of its parent's wrongness it takes back, negative when it shows things more wrongly
      (restoring one frame of a long drop reveals little; a car shown 0.5 m off where it was hidden
      reveals most of it)."""
    after = wrongness(c, space)
    changed = changed_cells(c, parent)
    falsity = float(after[changed].mean()) if changed.any() else 0.0
    return falsity, float((before - after).sum() / max(before.sum(), 1e-12))


def _features(moves: np.ndarray, gains: np.ndarray, seen: np.ndarray, count: int = len(MOVES)) -> np.ndarray:
    """A common intercept, one per move of the `count` (its departure from the common one), the gain
    (as a fraction of the round's largest), and the falsity and share revealed (`seen`, a row each).
    A move of index -1 has no move term (the prior's rows)."""
    onehot = np.zeros((len(moves), count))
    known = moves >= 0
    onehot[np.flatnonzero(known), moves[known]] = 1.0
    return np.column_stack([np.ones(len(moves)), onehot, gains, seen])


def penalty(count: int = len(MOVES)) -> np.ndarray:
    """L2 penalties of the model's weights with `count` moves: the common intercept and the gain slope
    are learnt from few rollouts, a move's departure from the common intercept only once that move has
    evidence of its own."""
    return np.array([0.1, *[1.0] * count, 0.1, 0.1, 0.1])


# rollouts' worth of each of the prior's two rows: until this search's own rollouts outweigh it, a
# step twice as bold is taken as much likelier to lose the collision, so the first rounds take
# moderate steps (as the paper's proposal, drawn uniformly among the improving ones, mostly does)
# rather than the boldest ones, which a planner's failure boundary rarely lets through
PRIOR_WEIGHT = 8.0


def fit_still_fails(moves: np.ndarray, gains: np.ndarray, seen: np.ndarray, failed: np.ndarray,
                    count: int = len(MOVES)) -> np.ndarray:
    """Weights of P(collides) = sigmoid(features . w), by weighted maximum likelihood with a prior
    that no gain keeps the verdict and the round's largest gain loses it (PRIOR_WEIGHT rollouts
    each). Every rollout informs the common intercept, so a few failures of any moves make the next
    round more careful."""
    x = _features(np.concatenate([moves, [-1, -1]]).astype(int), np.concatenate([gains, [0.0, 1.0]]),
                  np.concatenate([seen.reshape(-1, 2), [[0.5, 0.5], [0.5, 0.5]]]), count)
    y = np.concatenate([failed.astype(float), [1.0, 0.0]])
    weight = np.concatenate([np.ones(len(moves)), [PRIOR_WEIGHT, PRIOR_WEIGHT]])
    w = np.zeros(x.shape[1])
    l2 = penalty(count)
    for _ in range(100):  # Newton on an L2-regularised, weighted logistic regression
        p = 1.0 / (1.0 + np.exp(-x @ w))
        grad = x.T @ (weight * (y - p)) - l2 * w
        hess = -(x.T * (weight * p * (1.0 - p))) @ x - np.diag(l2)
        delta = np.linalg.solve(hess, grad)
        w -= delta
        if np.abs(delta).max() < 1e-9:
            break
    return w


def pick_batch(gain: np.ndarray, chance: np.ndarray, size: int, within: np.ndarray | None = None) -> list[int]:
    """Greedily, the candidates that most raise the expected best gain of the batch, each collision
    taken as independent: the first is the largest gain x chance, the next ones pay where the chosen
    ones fail (a safer candidate beside a bold one), and come from the candidates `within` the trust
    region while any of those are left (all: None)."""
    chosen: list[int] = []
    for _ in range(size):
        allowed = np.ones(gain.size, dtype=bool)
        allowed[chosen] = False
        if chosen and within is not None and (within & allowed).any():
            allowed &= within
        value = np.full(gain.size, -np.inf)
        for i in np.flatnonzero(allowed):
            batch = sorted([*chosen, int(i)], key=lambda k: -gain[k])
            miss, total = 1.0, 0.0
            for k in batch:  # the best gain realised is the largest among those that collide
                total += miss * chance[k] * gain[k]
                miss *= 1.0 - chance[k]
            value[i] = total
        chosen.append(int(np.argmax(value)))
    return chosen


# the trust region of a round's gains: after a round that lost every collision the batch's second
# candidate may gain at most RADIUS_SHRINK x the smaller of the last limit and that round's boldest
# gain; after a round that raised the best, RADIUS_GROW x the last limit. Where this planner's
# failure boundary hugs the best attack (obp_right_turn under nds: every step the model rated best
# revealed car 1 for too long), the second candidate's steps come down to the few that keep the
# collision, while the first stays the model's choice (IDM lets bold pushes through after failures).
# One gain undoes two losses, so the radius holds where a third of the second candidates keep the
# collision (a one-fifth success rule, as evolution strategies adapt their step, at a third): halved
# after every loss it held only where half did, and where a quarter of the small steps kept it
# (obp_right_turn) it sank to steps that gain nothing
RADIUS_SHRINK, RADIUS_GROW = 2.0**-0.5, 2.0


def next_radius(radius: float, improved: bool, all_lost: bool, boldest: float) -> float:
    """The trust region's radius for the next round, after a round whose boldest candidate gained
    `boldest`: it `improved` the best, or `all_lost` (every conclusive rollout lost the collision)."""
    if improved:
        return RADIUS_GROW * radius
    if all_lost:
        return RADIUS_SHRINK * min(radius, boldest)
    return radius


def trust_region(gain: np.ndarray, radius: float, slips: list[float]) -> np.ndarray:
    """Which candidates the batch's second pick may be: a gain at least the noise floor, the median
    of `slips` (how far the metrics of this search's colliding rollouts landed from their scores on
    their parents' rollouts), for a smaller step cannot be told from what re-rolling alone changes
    (at most the largest gain), and up to the radius; when no candidate lies between the two, the
    smallest step above the floor (a radius shrunk below the floor would otherwise leave the second
    pick unbounded for the rest of the search, as bold as the first)."""
    low = min(float(np.median(slips)) if slips else 0.0, gain.max())
    return (gain >= low) & (gain <= max(radius, gain[gain >= low].min()))


def guided_search(
    problem: AttackProblem, rng: np.random.Generator, cfg: GuidedConfig, budget: int, refine_iterations: int = 0,
    space: ErrorSpace = ErrorSpace(),
) -> Evaluation:
    """Rounds from the problem's best attack until it has logged `budget` rollouts; the best attack.

    Once the rollouts left come down to what the refine phase may use (2 x `refine_iterations`)
    after rounds have had as many, or no candidate scores above the best, the refine phase runs once
    on the best attack: a bisection re-detects the first frames of a drop more cheaply than random
    restores do, and under NDS, where displacing a car scores below dropping it, the last gains are
    there. Rounds then go on. A small budget stays with the rounds, where the large gains are."""
    moves: list[int] = []  # of every conclusive guided rollout: its move,
    gains: list[float] = []  # its scored gain over its parent as a fraction of its round's largest,
    shows: list[tuple[float, float]] = []  # what it showed (falsity, share revealed),
    failed: list[bool] = []  # and whether it still collided
    tried: set[bytes] = set()
    siblings: list[PerceptionErrors] = []  # the last round's collisions that did not become the best
    grandparent: PerceptionErrors | None = None  # the parent of the last round
    yaw = problem.scenario.agents.yaw
    names = moves_of(space.kinds)
    refined = refine_iterations == 0
    radius = np.inf  # the largest gain the batch's second candidate may try (`next_radius`)
    slips: list[float] = []  # of every colliding guided rollout: how far its metric is from its score
    while len(problem.log) < budget:
        if not refined and budget - len(problem.log) <= 2 * refine_iterations <= len(moves):
            refined = True
            refine_drops(problem, problem.found, refine_iterations)
            continue
        parent = problem.found
        frames = parent.rollout.num_frames
        pool: dict[bytes, tuple[int, PerceptionErrors]] = {}
        for sibling in siblings:  # siblings come with their grandparent
            c = merge(parent.errors, sibling, grandparent) if grandparent is not None else None
            if c is not None and _key(c) not in tried:
                pool.setdefault(_key(c), (names.index("merge"), c))
        context = MoveContext(true_agents(parent.rollout, problem.scenario), parent.rollout.ego, space, problem.scenario.dt)
        for _ in range(cfg.candidates):  # distinct candidates never rolled out, in the order drawn
            move, c = candidate(parent.errors, frames, rng, cfg, yaw, names, context)
            if c is not None and _key(c) not in tried:
                pool.setdefault(_key(c), (move, c))
        scored = [(problem.metric(c, parent.rollout) - parent.metric, move, c) for move, c in pool.values()]
        scored = [entry for entry in scored if entry[0] > 0]
        if not scored:  # nothing scores above the best attack: no round can improve it
            if refined:
                break
            refined = True
            refine_drops(problem, problem.found, refine_iterations)
            continue
        gain = np.array([g for g, _, _ in scored])
        relative = gain / gain.max()
        move = np.array([m for _, m, _ in scored])
        before = wrongness(parent.errors, space)
        seen = np.array([shown(c, parent.errors, before, space) for _, _, c in scored])
        w = fit_still_fails(np.array(moves, dtype=int), np.array(gains), np.array(shows).reshape(-1, 2),
                            np.array(failed, dtype=bool), len(names))
        chance = 1.0 / (1.0 + np.exp(-_features(move, relative, seen, len(names)) @ w))
        within = trust_region(gain, radius, slips)
        chosen = pick_batch(gain, chance, min(cfg.batch, budget - len(problem.log)), within)
        batch = [scored[i][2] for i in chosen]
        tried.update(_key(c) for c in batch)
        trials = problem.evaluate_many([(c, Phase.GUIDED, -1) for c in batch])
        grandparent = parent.errors
        conclusive = [trial for trial in trials if not trial.rollout.inconclusive]
        radius = next_radius(radius, problem.best is not parent,
                             bool(conclusive) and not any(trial.adversarial for trial in conclusive),
                             float(gain[chosen].max()))
        siblings = [trial.errors for trial in trials if trial.adversarial and trial is not problem.best]
        for i, trial in zip(chosen, trials):
            if trial.adversarial:
                slips.append(abs(parent.metric + gain[i] - trial.metric))
            if not trial.rollout.inconclusive:
                moves.append(int(move[i]))
                gains.append(float(relative[i]))
                shows.append(tuple(seen[i]))
                failed.append(trial.adversarial)
    return problem.found


class GuidedMethod:
    """The default method: the heuristic drops every agent before bisecting any (its rollouts may run
    at once), then `guided_search` spends the rest of the budget."""

    name = "guided"
    batched_heuristic = True
    phases: ClassVar[dict[Phase, PhaseLabel]] = {Phase.GUIDED: PhaseLabel("guided search", "tab:purple", "-."),
                                                 Phase.REFINE: refine.LABEL}

    def __init__(self, config: SearchConfig) -> None:
        self.config = config

    def tail_budget(self, used: int, budget: int) -> int:
        """`config.budget`, or when 0 the share of the paper's bound that follows the failure mode
        (`after_failure_bound`), `used` rollouts having found it. The paper's bound itself also counts
        bisections of agents whose drop did not collide, which a recording's dozens of cars make
        several times what the paper's search spends."""
        return self.config.budget or used + after_failure_bound(self.config)

    def run(self, problem: AttackProblem, heuristic: Evaluation, rng: np.random.Generator) -> None:
        guided_search(problem, rng, self.config.guided, problem.rollouts_allowed, self.config.refine_iterations,
                      self.config.errors)

    def still_owed(self, logged: Sequence[LogRow], share: int, best: Evaluation | None) -> int:
        """The rest of its share, which its rounds spend (they stop short only when no candidate
        scores above the best attack, after the refine phase has run)."""
        return share - len(logged)
