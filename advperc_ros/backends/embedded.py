"""The embedded backend: the system under attack built in this process (`Stack`)."""

import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from advperc_ros.backends.base import AttackedPlanner
from advperc_ros.configs import CoreConfigs
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.planners.registry import load_planner
from advperc_ros.core.rollout import RolloutResult, rollout
from advperc_ros.core.scenario import Scenario
from advperc_ros.core.tracker import make_tracker
from advperc_ros.heap import keep_freed_heap


class Stack:
    """The system under attack in this process, built from the core configs: tracker, planner, rollout.
    With `workers` > 1, `rollout_many` runs a batch on that many processes, each of which builds
    its own stack once (a planner is costly to build: ObP compiles its NLP)."""

    def __init__(self, scenario: Scenario, configs: CoreConfigs, bag_path: Path | None = None,
                 transport: Any = None) -> None:
        """`bag_path`, `transport`: the graph backend's, unused here (the registry gives both to every backend)."""
        self.scenario = scenario
        self.configs = configs
        self.config = configs.rollout
        self.tracker = make_tracker(configs.tracker)
        self.planner = load_planner(configs.planner.name, configs.planning_context(scenario), configs.planner.params)
        self.attacked_planner = AttackedPlanner(configs.planner.name)
        self._pool: ProcessPoolExecutor | None = None

    def rollout(self, errors: PerceptionErrors, record: bool = False) -> RolloutResult:
        return rollout(self.scenario, errors, self.tracker, self.planner, self.config, record=record)

    def rollout_many(self, batch: list[PerceptionErrors]) -> list[RolloutResult]:
        """The rollouts of a batch, in its order; the same results whatever the workers."""
        workers = self.configs.execution.workers
        if workers == 1:
            return [self.rollout(errors) for errors in batch]
        if self._pool is None:  # spawn: the parent may run threads (rclpy) that fork would copy mid-state
            self._pool = ProcessPoolExecutor(workers, multiprocessing.get_context("spawn"), initializer=_start_worker,
                                             initargs=(self.scenario, self.configs))
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


def _start_worker(scenario: Scenario, configs: CoreConfigs) -> None:
    global _worker_stack
    keep_freed_heap()
    _worker_stack = Stack(scenario, configs)


def _worker_rollout(errors: PerceptionErrors) -> RolloutResult:
    if _worker_stack is None:
        raise RuntimeError("a pool worker's stack is built by its initializer, _start_worker")
    return _worker_stack.rollout(errors)
