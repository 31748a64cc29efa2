"""An attack end to end: replay a ground-truth bag, search, return the outcome. The orchestrator
node and `advperc attack` both call this. Rollouts run embedded (`Stack`, one process) or through
the node graph over DDS (`advperc_ros.graph.GraphRollouts`), chosen by `rollout_backend`; the
search cannot tell them apart."""

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from tqdm import tqdm

from advperc_ros.core.errors import PerceptionErrors
from advperc_ros.core.planners.base import load_planner
from advperc_ros.core.rollout import RolloutResult, rollout
from advperc_ros.core.scenario import Scenario
from advperc_ros.core.search.heuristic import heuristic_search
from advperc_ros.core.search.problem import AttackProblem, Evaluation, LogRow
from advperc_ros.core.search.random_search import RandomSearchConfig, random_search
from advperc_ros.core.search.refine import refine_drops
from advperc_ros.core.tracker import Tracker
from advperc_ros.params import AttackParams, planning_context, rollout_config, tracker_config

EXTERNAL = "external"  # the `planner` of a report whose planner was a node of someone else's


@dataclass(frozen=True)
class AttackedPlanner:
    """Which planner the rollouts went through: the params' own, or an external node (its name as
    the middleware tells it, "" where it cannot), so the report names the system attacked."""

    name: str
    node: str | None = None


@dataclass(frozen=True)
class AttackOutcome:
    scenario: Scenario
    params: AttackParams  # as run: `planner` is EXTERNAL when an external node planned
    heuristic_best: Evaluation | None  # None when no agent is influential
    best: Evaluation | None  # best adversarial evaluation of the whole search
    recorded: RolloutResult | None  # the best attack rolled out again with tracks and plans kept
    log: list[LogRow]
    wall_time_s: float
    planner_node: str | None = None  # the external planner node, when one planned


class Stack:
    """The system under attack, built from the params: tracker + planner + rollout settings."""

    def __init__(self, scenario: Scenario, params: AttackParams) -> None:
        values = params.flat()
        self.scenario = scenario
        self.config = rollout_config(values)
        self.tracker = Tracker(tracker_config(values))
        self.planner = load_planner(params.planner, planning_context(values, scenario), params.planner_params)
        self.attacked_planner = AttackedPlanner(params.planner)

    def rollout(self, errors, record: bool = False) -> RolloutResult:
        return rollout(self.scenario, errors, self.tracker, self.planner, self.config, record=record)


class Rollouts(Protocol):
    """What the search needs of a backend: one rollout of an error tensor; which planner it runs."""

    attacked_planner: AttackedPlanner

    def rollout(self, errors: PerceptionErrors, record: bool = False) -> RolloutResult: ...


@contextmanager
def open_rollouts(scenario: Scenario, params: AttackParams, bag_path: Path, transport: Any = None) -> Iterator[Rollouts]:
    """The backend `rollout_backend` names, ready to use and shut down on exit. `transport`
    (graph backend, nodes not spawned) lets an rclpy orchestrator reach nodes over its own node."""
    if params.rollout_backend != "graph":
        yield Stack(scenario, params)
        return
    from advperc_ros.graph import GraphRollouts

    with GraphRollouts(scenario, params, bag_path, transport) as graph:
        yield graph


def run_attack(scenario: Scenario, params: AttackParams, progress: bool = True,
               rollouts: Rollouts | None = None) -> AttackOutcome:
    """Both searches over `rollouts` (default: embedded)."""
    started = time.perf_counter()
    backend = rollouts if rollouts is not None else Stack(scenario, params)
    num_agents = scenario.agents.shape[1]
    search = params.search
    iterations = search.heuristic.iterations
    budget = 1 + num_agents * (1 + 2 * iterations) + search.random.steps + 2 * search.refine.iterations
    bar = tqdm(
        total=budget, desc=scenario.name, unit="rollout", disable=not progress, file=sys.stderr, mininterval=1.0
    )

    def on_rollout(row: LogRow) -> None:
        phase = {"random": "random search", "refine": "refine"}.get(row.phase, "heuristic")
        bar.set_description(f"{scenario.name} ({phase})", refresh=False)
        bar.set_postfix(best=f"{row.best_metric:.4f}", refresh=False)
        bar.update()

    problem = AttackProblem(scenario, backend.rollout, params.objective, on_rollout=on_rollout)
    try:
        modes = heuristic_search(problem, iterations)
        heuristic_best = max(modes, key=lambda m: m.metric) if modes else None
        if heuristic_best is not None:
            cfg = RandomSearchConfig(steps=search.random.steps, proposals=search.random.proposals,
                                     max_offset=search.random.max_offset, yaw_std=search.random.yaw_std)
            random_search(problem, heuristic_best, np.random.default_rng(params.seed), cfg)
            if search.refine.iterations > 0:
                refine_drops(problem, problem.best, search.refine.iterations)
    finally:
        bar.close()
    best = problem.best
    recorded = backend.rollout(best.errors, record=True) if best is not None else None
    attacked = backend.attacked_planner
    if attacked.node is not None:
        params = replace(params, planner=EXTERNAL, planner_params={})
    return AttackOutcome(
        scenario=scenario,
        params=params,
        heuristic_best=heuristic_best,
        best=best,
        recorded=recorded,
        log=problem.log,
        wall_time_s=time.perf_counter() - started,
        planner_node=attacked.node,
    )
