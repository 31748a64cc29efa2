"""The embedded backend: the system under attack built in this process (`Stack`)."""

import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from advperc_ros.backends.base import AttackedPlanner
from advperc_ros.configs import CoreConfigs, core_configs
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.planners.registry import load_planner
from advperc_ros.core.rollout import RolloutResult, rollout
from advperc_ros.core.scenario import Scenario
from advperc_ros.core.tracker import make_tracker
from advperc_ros.heap import keep_freed_heap
from advperc_ros.params import AttackParams, params_from_values


class Stack:
    """The system under attack in this process, built from the params: tracker, planner, rollout.
    With `workers` > 1, `rollout_many` runs a batch on that many processes, each of which builds
    its own stack once (a planner is costly to build: ObP compiles its NLP)."""

    def __init__(self, scenario: Scenario, params: AttackParams, configs: CoreConfigs | None = None,
                 bag_path: Path | None = None, transport: Any = None) -> None:
        """`configs`: the params' core configs, when the caller built them (else built here);
        `bag_path`, `transport`: the graph backend's, unused here (the registry gives both to every backend)."""
        configs = configs if configs is not None else core_configs(params)
        self.scenario = scenario
        self.params = params
        self.config = configs.rollout
        self.tracker = make_tracker(configs.tracker)
        self.planner = load_planner(params.planner, configs.planning_context(scenario), params.planner_params)
        self.attacked_planner = AttackedPlanner(params.planner)
        self._pool: ProcessPoolExecutor | None = None

    def rollout(self, errors: PerceptionErrors, record: bool = False) -> RolloutResult:
        return rollout(self.scenario, errors, self.tracker, self.planner, self.config, record=record)

    def rollout_many(self, batch: list[PerceptionErrors]) -> list[RolloutResult]:
        """The rollouts of a batch, in its order; the same results whatever the workers."""
        if self.params.workers == 1:
            return [self.rollout(errors) for errors in batch]
        if self._pool is None:  # spawn: the parent may run threads (rclpy) that fork would copy mid-state
            self._pool = ProcessPoolExecutor(self.params.workers, multiprocessing.get_context("spawn"),
                                             initializer=_start_worker, initargs=(self.scenario, self.params.values(),
                                                                                   self.params.source))
        return list(self._pool.map(_worker_rollout, batch))

    def __enter__(self) -> "Stack":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None


_worker_stack: Stack | None = None  # a pool worker's own stack


def _start_worker(scenario: Scenario, values: dict, source) -> None:
    global _worker_stack
    keep_freed_heap()
    _worker_stack = Stack(scenario, params_from_values(values, source))


def _worker_rollout(errors: PerceptionErrors) -> RolloutResult:
    if _worker_stack is None:
        raise RuntimeError("a pool worker's stack is built by its initializer, _start_worker")
    return _worker_stack.rollout(errors)
