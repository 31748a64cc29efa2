"""What both searches share: rolling out an error tensor, scoring it, and logging every rollout."""

from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.metrics.scores import PerceptionScores, score
from advperc_ros.core.pem import default_pem, features
from advperc_ros.core.perception_errors import PAPER_KINDS, PerceptionErrors, inject
from advperc_ros.core.perception_errors.restriction import Restriction, Scene
from advperc_ros.core.rollout import RolloutResult, true_agents
from advperc_ros.core.rules.verdict import AttackedRule
from advperc_ros.core.scenario import Scenario
from advperc_ros.exceptions import BudgetSpent

OBJECTIVES = ("nds", "nds_t", "pem_ll")


class Phase(str, Enum):
    """Which step of the search a rollout belongs to (the `phase` column of search_log.csv)."""

    GROUND_TRUTH = "ground_truth"
    HEURISTIC_DROP = "heuristic_drop"  # Algorithm 1: one agent's whole track dropped
    HEURISTIC_START = "heuristic_start"  # Algorithm 1: bisecting the drop's latest start
    HEURISTIC_END = "heuristic_end"  # Algorithm 1: bisecting its earliest end
    JOINT = "joint"  # beyond the paper, when no single drop collides: several agents dropped at once, bisected
    PHANTOM = "phantom"  # beyond the paper, when ghosts are on: a ghost standing just ahead of the ego
    APPROACH = "approach"  # beyond the paper, when no drop collides: nearby cars shown displaced, towards a collision
    RANDOM = "random"  # Algorithm 2
    REFINE = "refine"  # beyond the paper: re-detecting the start of dropped runs
    GUIDED = "guided"  # beyond the paper: the guided search's rounds
    ROBUSTNESS = "robustness"  # perturbations of a found attack (paper figure 5)

    def __str__(self) -> str:
        return self.value

    @property
    def heuristic(self) -> bool:
        return self in (Phase.GROUND_TRUTH, Phase.HEURISTIC_DROP, Phase.HEURISTIC_START, Phase.HEURISTIC_END,
                        Phase.JOINT, Phase.PHANTOM)


@dataclass(frozen=True)
class PhaseLabel:
    """How a phase of the search is shown, which the stage that runs it chooses: what the progress bar
    and the metric plot's legend call it, and its stretch of the plot's best-metric curve (so the
    plots name no phase, and a new search method brings its own)."""

    name: str
    color: str  # a matplotlib colour
    line: str  # a matplotlib line style


@dataclass(frozen=True)
class Evaluation:
    """One rollout of an error tensor, with its perception scores over the rollout's frames."""

    errors: PerceptionErrors
    rollout: RolloutResult
    scores: PerceptionScores
    metric: float

    @property
    def adversarial(self) -> bool:
        return self.rollout.collided


@dataclass
class LogRow:
    """One rollout of the search as search_log.csv holds it: what was tried, what it scored and
    whether it collided, so a search can be followed and plotted rollout by rollout."""

    rollout: int
    phase: Phase
    agent: int  # agent id the step concerns, -1 for none
    metric: float
    nds: float
    nds_t: float
    min_signed_distance: float
    collided: bool
    inconclusive: str
    planner_failures: int | None  # planner solves that failed and fell back (None: not reported)
    accepted: bool  # the search adopted this rollout (both algorithms adopt exactly the failing ones)
    best_metric: float  # best metric of an adversarial rollout so far (nan before the first)
    rule_value: float | None = None  # the attacked rule's value r when it is not a contact rule (`verdict`), else None


def perception_scores(agents: BoxSequence, errors: PerceptionErrors, frames: int, ego_xy: np.ndarray,
                      phi: np.ndarray | None = None, kinds: tuple[str, ...] = PAPER_KINDS) -> PerceptionScores:
    """m(I(y, e), y) over the first `frames` frames of a rollout whose true agents were `agents` (a scenario's
    recording, or its rollout's simulation under reactive traffic: `rollout.true_agents`) and whose ego was at ego_xy;
    PEM LL under the shipped model for the error `kinds` the search may use (and any `errors` has): a
    search beyond the paper's kinds is judged by the model whose terms cover ghosts, flips,
    velocities, sizes and latency, whichever kinds its attack ends up using (a pure drop included)."""
    # inject over the whole scenario first: a detection's confidence depends on its frame and
    # agent only, never on where this rollout stopped
    return score(agents.frames(frames), inject(agents, errors).frames(frames), ego_xy,
                 pem=default_pem((*kinds, *errors.kinds)), phi=phi)


def kind_costs(scenario: Scenario, evaluation: Evaluation, objective: str,
               kinds: tuple[str, ...] = PAPER_KINDS) -> dict[str, float]:
    """Per error kind the attack uses, what it costs the objective: the objective on the attack's rollout
    with that kind's errors taken out, less the attack's own (a drop taken out shows the car, perfectly
    unless another kind's error is on it); `kinds`: the search's, as `perception_scores` takes them."""
    rollout = evaluation.rollout
    agents = true_agents(rollout, scenario)
    return {kind: getattr(perception_scores(agents, evaluation.errors.without(kind), rollout.num_frames,
                                            rollout.ego_xy, kinds=kinds), objective) - evaluation.metric
            for kind in evaluation.errors.used_kinds(rollout.num_frames)}


@dataclass
class AttackProblem:
    """Binds a scenario, a rollout function and an objective; counts and logs every rollout."""

    scenario: Scenario
    run_rollout: Callable[[PerceptionErrors], RolloutResult]
    objective: str
    on_rollout: Callable[[LogRow], None] | None = None
    # several rollouts at once (a backend's worker pool); None: one after another
    run_rollouts: Callable[[list[PerceptionErrors]], list[RolloutResult]] | None = None
    budget: int | None = None  # rollouts allowed; one more raises BudgetSpent
    kinds: tuple[str, ...] = PAPER_KINDS  # the error kinds the search may use: PEM LL's model (`perception_scores`)
    log: list[LogRow] = field(default_factory=list)
    best: Evaluation | None = None
    truth: Evaluation | None = None  # the first ground-truth rollout logged: perfect perception, for the report's rules
    # the rule attacked when it is not a contact rule: every rollout is judged by it here, once, before it is
    # scored and logged (against the ground truth's rollout, the first logged); None: the backends' contact verdict
    attacked_rule: AttackedRule | None = None
    # a requirement's error space: every tensor projected onto it before it is scored or rolled out, its distance
    # bin read from the ground truth's rollout; None: the search's whole error space
    restriction: Restriction | None = None
    _scene: Scene | None = field(default=None, repr=False)
    _reference: RolloutResult | None = field(default=None, repr=False)
    _reference_phi: np.ndarray | None = field(default=None, repr=False)

    @property
    def found(self) -> Evaluation:
        """`best`, where a phase runs only once an attack was found (the search methods' own phases)."""
        if self.best is None:
            raise RuntimeError("no attack has been found: this phase runs only after one")
        return self.best

    @property
    def rollouts_allowed(self) -> int:
        """`budget`, which `run_search` sets before any phase runs."""
        if self.budget is None:
            raise RuntimeError("the search has no budget yet: run_search sets it")
        return self.budget

    def __post_init__(self) -> None:
        if self.objective not in OBJECTIVES:
            raise ValueError(f"unknown objective '{self.objective}' (known: {', '.join(OBJECTIVES)})")

    def scores(self, errors: PerceptionErrors, rollout: RolloutResult, phi=None) -> PerceptionScores:
        """m(I(y, e), y) over the frames of `rollout`, on its true agents (`rollout.true_agents`)."""
        return perception_scores(true_agents(rollout, self.scenario), errors, rollout.num_frames, rollout.ego_xy, phi,
                                 self.kinds)

    def restricted(self, errors: PerceptionErrors) -> PerceptionErrors:
        """`errors` projected onto the requirement's error space (unchanged without one). Before the ground
        truth is rolled out there is no distance to go by, and nothing but perfect perception is rolled out."""
        if self.restriction is None:
            return errors
        if self.truth is None:
            blank = PerceptionErrors.none(*errors.shape, errors.kinds, errors.ghost_slots).arrays()
            if any(not np.array_equal(array, blank[name]) for name, array in errors.arrays().items()):
                raise RuntimeError("a requirement search rolled out errors before the ground truth, whose rollout "
                                   "its distance bin is measured on")
            return errors
        if self._scene is None:
            rollout, restriction = self.truth.rollout, self.restriction
            truth = true_agents(rollout, self.scenario)
            self._scene = Scene.of(truth.x, truth.y, truth.yaw, self.scenario.agents.valid, rollout.ego_xy,
                                   self.scenario.dt, restriction.near, restriction.far)
        return self.restriction.project(errors, self._scene)

    def metric(self, errors: PerceptionErrors, reference: RolloutResult) -> float:
        """The objective of errors judged on a previous rollout's ground truth (Algorithm 2)."""
        errors = self.restricted(errors)
        if self._reference is not reference:  # proposals of one step share the rollout: and its PEM features
            self._reference = reference
            self._reference_phi = features(true_agents(reference, self.scenario).frames(reference.num_frames),
                                           reference.ego_xy)
        scores = self.scores(errors, reference, self._reference_phi)
        return getattr(scores, self.objective)

    def evaluate(self, errors: PerceptionErrors, phase: Phase, agent: int = -1) -> Evaluation:
        """Roll out errors, score them on that rollout, log the rollout."""
        return self.evaluate_many([(errors, phase, agent)])[0]

    def evaluate_many(self, batch: list[tuple[PerceptionErrors, Phase, int]]) -> list[Evaluation]:
        """`evaluate` of each (errors, phase, agent), logged in order; the rollouts may run at once
        (`run_rollouts`)."""
        if self.budget is not None and len(self.log) + len(batch) > self.budget:
            raise BudgetSpent(f"{len(self.log)} of {self.budget} rollouts run; {len(batch)} more asked for")
        if self.restriction is not None and self.truth is None and len(batch) > 1 and batch[0][1] == Phase.GROUND_TRUTH:
            # the rest of the batch is projected by distances measured on the ground truth's rollout
            return self.evaluate_many(batch[:1]) + self.evaluate_many(batch[1:])
        batch = [(self.restricted(e), phase, agent) for e, phase, agent in batch]
        errors = [item[0] for item in batch]
        if self.run_rollouts is not None and len(batch) > 1:
            results = self.run_rollouts(errors)
        else:
            results = [self.run_rollout(e) for e in errors]
        return [self._record(e, result, phase, agent) for (e, phase, agent), result in zip(batch, results)]

    def _record(self, errors: PerceptionErrors, result: RolloutResult, phase: Phase, agent: int) -> Evaluation:
        if self.attacked_rule is not None:
            result = self.attacked_rule.judge(result, None if self.truth is None else self.truth.rollout)
        scores = self.scores(errors, result)
        evaluation = Evaluation(errors, result, scores, getattr(scores, self.objective))
        if phase == Phase.GROUND_TRUTH and self.truth is None:
            self.truth = evaluation
        if evaluation.adversarial and (self.best is None or evaluation.metric > self.best.metric):
            self.best = evaluation
        row = LogRow(
            rollout=len(self.log) + 1,
            phase=phase,
            agent=agent,
            metric=evaluation.metric,
            nds=scores.nds,
            nds_t=scores.nds_t,
            min_signed_distance=result.min_signed_distance,
            collided=result.collided,
            inconclusive=result.inconclusive or "",
            planner_failures=result.planner_failures,
            accepted=evaluation.adversarial and phase != Phase.GROUND_TRUTH,
            best_metric=self.best.metric if self.best is not None else float("nan"),
            rule_value=result.verdict,
        )
        self.log.append(row)
        if self.on_rollout is not None:
            self.on_rollout(row)
        return evaluation
