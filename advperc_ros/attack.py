"""An attack end to end: replay a ground-truth bag, search, return the outcome. The orchestrator
node and `advperc attack` both call this. Rollouts run embedded (`Stack`, one process) or through
the node graph over DDS (`advperc_ros.graph.GraphRollouts`), chosen by `rollout_backend`; the
search cannot tell them apart."""

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from tqdm import tqdm

from advperc_ros.core.errors import PerceptionErrors
from advperc_ros.core.planners.base import PlanningContext
from advperc_ros.core.planners.registry import load_planner
from advperc_ros.core.rollout import RolloutConfig, RolloutResult, rollout
from advperc_ros.core.scenario import Scenario
from advperc_ros.core.search.heuristic import heuristic_search
from advperc_ros.core.search.problem import AttackProblem, Evaluation, LogRow
from advperc_ros.core.search.random_search import RandomSearchConfig, random_search
from advperc_ros.core.search.refine import refine_drops
from advperc_ros.core.tracker import Tracker, TrackerConfig
from advperc_ros.params import AttackParams, ParamsError


@dataclass(frozen=True)
class AttackOutcome:
    scenario: Scenario
    params: AttackParams
    heuristic_best: Evaluation | None  # None when no agent is influential
    best: Evaluation | None  # best adversarial evaluation of the whole search
    recorded: RolloutResult | None  # the best attack rolled out again with tracks and plans kept
    log: list[LogRow]
    wall_time_s: float


def resolve_bag(params: AttackParams) -> Path:
    """The bag named in the params: as given, next to the params file, or in the package share."""
    return find_bag(params["bag"], params.source)


def find_bag(bag: str, source: Path | None) -> Path:
    """`bag` as given, next to the params file `source`, or in the package share."""
    name = Path(bag)
    candidates = [name]
    if not name.is_absolute():
        if source is not None:
            candidates.append(source.parent / name)
        candidates.append(Path(sys.prefix) / "share" / "advperc_ros" / name)
    for candidate in candidates:
        if candidate.exists():
            return candidate
    where = source or "params"
    raise ParamsError(f"{where}: parameter 'bag' names '{name}', which does not exist")


class Stack:
    """The system under attack, built from the params: tracker + planner + rollout settings."""

    def __init__(self, scenario: Scenario, params: AttackParams) -> None:
        self.scenario = scenario
        self.config = RolloutConfig(
            ego_length=params["ego.length"], ego_width=params["ego.width"], stop_at_collision=params["stop_at_collision"]
        )
        context = PlanningContext(
            route=scenario.route, lanes=scenario.lanes, dt=scenario.dt,
            ego_length=self.config.ego_length, ego_width=self.config.ego_width,
        )
        self.tracker = Tracker(TrackerConfig(gate=params["tracker.gate"], max_age=params["tracker.max_age"]))
        self.planner = load_planner(params["planner"], context, params.planner_params)

    def rollout(self, errors, record: bool = False) -> RolloutResult:
        return rollout(self.scenario, errors, self.tracker, self.planner, self.config, record=record)


class Rollouts(Protocol):
    """What the search needs of a backend: one rollout of an error tensor."""

    def rollout(self, errors: PerceptionErrors, record: bool = False) -> RolloutResult: ...


@contextmanager
def open_rollouts(scenario: Scenario, params: AttackParams, bag_path: Path, transport: Any = None) -> Iterator[Rollouts]:
    """The backend `rollout_backend` names, ready to use and shut down on exit. `transport`
    (graph backend, nodes not spawned) lets an rclpy orchestrator reach nodes over its own node."""
    if params["rollout_backend"] != "graph":
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
    iterations = params["search.heuristic.iterations"]
    budget = 1 + num_agents * (1 + 2 * iterations) + params["search.random.steps"] + 2 * params["search.refine.iterations"]
    bar = tqdm(
        total=budget, desc=scenario.name, unit="rollout", disable=not progress, file=sys.stderr, mininterval=1.0
    )

    def on_rollout(row: LogRow) -> None:
        phase = {"random": "random search", "refine": "refine"}.get(row.phase, "heuristic")
        bar.set_description(f"{scenario.name} ({phase})", refresh=False)
        bar.set_postfix(best=f"{row.best_metric:.4f}", refresh=False)
        bar.update()

    problem = AttackProblem(scenario, backend.rollout, params["objective"], on_rollout=on_rollout)
    try:
        modes = heuristic_search(problem, iterations)
        heuristic_best = max(modes, key=lambda m: m.metric) if modes else None
        if heuristic_best is not None:
            cfg = RandomSearchConfig(
                steps=params["search.random.steps"],
                proposals=params["search.random.proposals"],
                max_offset=params["search.random.max_offset"],
                yaw_std=params["search.random.yaw_std"],
            )
            random_search(problem, heuristic_best, np.random.default_rng(params["seed"]), cfg)
            if params["search.refine.iterations"] > 0:
                refine_drops(problem, problem.best, params["search.refine.iterations"])
    finally:
        bar.close()
    best = problem.best
    recorded = backend.rollout(best.errors, record=True) if best is not None else None
    return AttackOutcome(
        scenario=scenario,
        params=params,
        heuristic_best=heuristic_best,
        best=best,
        recorded=recorded,
        log=problem.log,
        wall_time_s=time.perf_counter() - started,
    )
