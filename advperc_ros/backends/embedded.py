"""The embedded backend: the system under attack built in this process (`Stack`), its rollouts forked
from snapshots of earlier ones (core.forks)."""

import logging
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from advperc_ros.backends.base import AttackedPlanner
from advperc_ros.configs import CoreConfigs
from advperc_ros.core.forks import DEEP_COPY, WHOLE, Forks, PlannerSnapshots
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.planners.registry import load_planner
from advperc_ros.core.rollout import RolloutResult, identical, rollout
from advperc_ros.core.scenario import Scenario
from advperc_ros.core.tracker import make_tracker
from advperc_ros.heap import keep_freed_heap

log = logging.getLogger("advperc_ros.backends.embedded")


class Stack:
    """The system under attack in this process, built from the core configs: tracker, planner, rollout.
    With `workers` > 1, `rollout_many` runs a batch on that many processes, each of which builds
    its own stack once (a planner is costly to build: ObP compiles its NLP). Each process forks its rollouts
    from snapshots of its earlier ones, within `fork_memory` MB: the results are a full rollout's, bit for
    bit; a planner without snapshot() is deep-copied once a forked rollout of it was checked against a full
    one, or rolled out whole, and the log says which, once."""

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
        self.forks = Forks(configs.execution.fork_memory << 20, PlannerSnapshots.of(self.planner))
        self._trusted = self.forks.planner.how != DEEP_COPY  # deep copies are trusted once checked
        self._said_whole = False
        if self.forks.planner.how == WHOLE and self.forks.memory > 0:
            self._say_whole("no snapshot(), and its attributes do not deep-copy")

    def rollout(self, errors: PerceptionErrors, record: bool = False) -> RolloutResult:
        forks = self.forks
        result = rollout(self.scenario, errors, self.tracker, self.planner, self.config, record=record, forks=forks)
        # the first rollout forked from deep copies that planned beyond its fork, whose plan was followed
        if not self._trusted and forks.last_fork is not None and result.num_frames > forks.last_fork + 2:
            full = rollout(self.scenario, errors, self.tracker, self.planner, self.config, record=record)
            self._trusted = True
            if identical(result, full):
                log.info(f"planner {self.configs.planner.name}: no snapshot(), but a rollout forked from deep copies "
                         f"of it at frame {forks.last_fork} equals the full rollout: rollouts fork from deep copies")
            else:
                forks.disable("no snapshot(), and a rollout forked from deep copies of it differs from the full one")
            result = full
        if forks.disabled_because is not None and not self._said_whole:
            self._said_whole = True
            self._say_whole(forks.disabled_because)
        return result

    def _say_whole(self, why: str) -> None:
        log.info(f"planner {self.configs.planner.name}: {why}; every rollout runs from frame 0")

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
        if self.forks.rollouts:  # for benchmarks (fork_bench.py turns it on), not the attack's output
            log.debug(f"this process: {self.forks.summary()}")
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
