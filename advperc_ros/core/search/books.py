"""The search's own books: every rollout it logs, under the stage that logged it, and after each one
the estimate of the rollouts still to come, which a progress bar draws without knowing the stages.

Each stage says what it may still run, at most, from the rows it logged: Algorithm 1
(`heuristic.still_owed`), the phantom obstacles, the joint drops, the approach phase and the search
method (`SearchMethod.still_owed`). The estimate adds the stage running, the stages that run
whatever it finds (the phantom obstacles, when ghosts are on) and the method's share, which follows
any failure mode: it is counted from the first rollout on, so the total does not jump when the first
drop collides, and a drop not rolled out yet is counted with the bisections it would run. The joint
drops and the approach phase run only when nothing collided, and are counted from their first
rollout (ahead of time they would add their hundred-odd rollouts to every search's estimate). A
stage before the one running owes nothing; the whole is capped by the budget in force.

So the total never exceeds the budget in force. Where a drop or a phantom obstacle collides, every
figure is a worst case given the rows logged (but the paper's refine share, should its random search
leave the best attack more dropped runs than the two the bound counts), so the total shown from the
first rollout on only falls, and never below the rollouts the search goes on to run; with the guided
method, whose rounds spend their share unless no candidate scores above the best attack, it ends at
them. It rises only at the first rollout of the joint drops and of the approach phase.
"""

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

from advperc_ros.core.search import approach, heuristic, joint, phantom
from advperc_ros.core.search.config import SearchConfig
from advperc_ros.core.search.method import SearchMethod
from advperc_ros.core.search.problem import AttackProblem, LogRow, Phase, PhaseLabel

# the phases every search runs before its method's, and how they are shown
SHARED_PHASES: Mapping[Phase, PhaseLabel] = {**heuristic.PHASES, **phantom.PHASES, **joint.PHASES, **approach.PHASES}


@dataclass(frozen=True)
class Estimate:
    """What the search says after each rollout, which is all its progress bar draws: the rollout just
    run (its number counts the rollouts run), those still to come at most as far as the search knows
    (never past its budget), what to call the phase, and the collisions found so far."""

    row: LogRow
    to_come: int
    label: str
    collisions: int  # conclusive rollouts that collided
    inconclusive: int = 0  # rollouts so far that a crashed, hung or failing stack left inconclusive

    @property
    def run(self) -> int:
        return self.row.rollout

    @property
    def total(self) -> int:
        return self.run + self.to_come

    @property
    def best(self) -> float | None:
        """The best adversarial metric so far; None before the first collision."""
        return None if math.isnan(self.row.best_metric) else self.row.best_metric


@dataclass(frozen=True)
class Stage:
    """A stage before the method as the books keep it: its phases, what it may still run given its
    rows, and whether it runs whatever the stages before it find (then it is counted before it begins)."""

    phases: Mapping[Phase, PhaseLabel]
    still_owed: Callable[[Sequence[LogRow]], int]
    counted_ahead: bool


class Books:
    """The rows of one search by stage, the last stage its method's; `record` each row the problem logs."""

    def __init__(self, problem: AttackProblem, config: SearchConfig, method: SearchMethod,
                 on_estimate: Callable[[Estimate], None]) -> None:
        agents, iterations = problem.scenario.agents.shape[1], config.heuristic_iterations
        self.problem, self.method, self.on_estimate = problem, method, on_estimate
        self.stages = (
            Stage(heuristic.PHASES, lambda rows: heuristic.still_owed(rows, agents, iterations, method.batched_heuristic),
                  True),
            Stage(phantom.PHASES, lambda rows: phantom.still_owed(rows, config.errors), True),
            Stage(joint.PHASES, lambda rows: joint.still_owed(rows, config.joint_max_agents, agents, iterations), False),
            Stage(approach.PHASES, lambda rows: approach.still_owed(rows, config.approach_steps, agents), False),
        )
        self.stage_of = {phase: i for i, stage in enumerate(self.stages) for phase in stage.phases}
        self.stage_of.update(dict.fromkeys(method.phases, len(self.stages)))
        self.labels = {**SHARED_PHASES, **method.phases}
        self.logged: list[list[LogRow]] = [[] for _ in range(len(self.stages) + 1)]
        self.current = 0  # the stage of the last row
        self.collisions = 0
        self.inconclusive = 0

    def record(self, row: LogRow) -> None:
        """Book `row` under its stage and send the estimate after it."""
        self.current = self.stage_of[row.phase]
        self.logged[self.current].append(row)
        self.collisions += row.collided and not row.inconclusive
        self.inconclusive += bool(row.inconclusive)
        self.on_estimate(Estimate(row, self.to_come(row.rollout), self.labels[row.phase].name, self.collisions,
                                  self.inconclusive))

    def to_come(self, run: int) -> int:
        """Rollouts still to come at most, `run` having run: the stage running, those counted ahead
        after it, then the method's, within the budget."""
        ahead = [i for i in range(self.current, len(self.stages)) if i == self.current or self.stages[i].counted_ahead]
        before_method = sum(self.stages[i].still_owed(self.logged[i]) for i in ahead)
        own = self.logged[-1]
        start = own[0].rollout - 1 if own else run + before_method  # the rollouts run before the method
        budget = self.problem.rollouts_allowed
        share = self.method.tail_budget(start, budget) - start
        owed = before_method + self.method.still_owed(own, share, self.problem.best)
        return max(0, min(budget - run, owed))


@contextmanager
def kept(problem: AttackProblem, config: SearchConfig, method: SearchMethod,
         on_estimate: Callable[[Estimate], None] | None) -> Iterator[None]:
    """While the search runs, the books hear every row the problem logs (after the listener it had)
    and send `on_estimate` the estimate; nothing is kept when it is None."""
    heard = problem.on_rollout
    if on_estimate is None:
        yield
        return
    books = Books(problem, config, method, on_estimate)

    def record(row: LogRow) -> None:
        if heard is not None:
            heard(row)
        books.record(row)

    problem.on_rollout = record
    try:
        yield
    finally:
        problem.on_rollout = heard
