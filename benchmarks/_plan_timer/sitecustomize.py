"""Loaded by every interpreter that has this folder on its path (planner_process_cost.py and
frame_gap.py put it on the graph nodes' PYTHONPATH). Benchmark-only: nothing in the package loads it.

- wraps the planner classes' `plan`: each call's thread CPU time is tallied (`tally()`), and its wall
  clock start and end (`time.perf_counter`, CLOCK_MONOTONIC: one clock for every process) are kept;
- in a graph node, marks when the player's `on_plan` and the planner node's `on_odometry` are
  entered (the node classes live in `__main__`, as `python -m advperc_ros.nodes.<node>` runs them, so
  they are wrapped when `run_node` starts), and when each publish on either transport starts and ends.

Where ADVPERC_PLAN_TIMER names a folder, SIGUSR1 writes `<pid>.json` there: {"calls", "seconds" (the
tally), "plans" [[start, end], ...], "marks" [[what, start, end], ...]} with what was kept since the
last signal, which is then forgotten (the tally is not)."""

import contextlib
import json
import os
import signal
import sys
import time

_tally = [0, 0.0]
_plans: list[tuple[float, float]] = []
_marks: list[tuple[str, float, float]] = []
NODE_ENTRIES = {"ScenarioPlayer": ("on_plan",), "PlannerNode": ("on_odometry",)}


def tally() -> tuple[int, float]:
    """(plan() calls, their thread CPU seconds) in this process so far."""
    return _tally[0], _tally[1]


def plans() -> list[tuple[float, float]]:
    """The (start, end) wall clock of every plan() call since the last `forget()` (or signal)."""
    return list(_plans)


def forget() -> None:
    _plans.clear()
    _marks.clear()


def _timed(plan):
    def timed(self, *args, **kwargs):
        started, cpu = time.perf_counter(), time.thread_time()
        try:
            return plan(self, *args, **kwargs)
        finally:
            _tally[0] += 1
            _tally[1] += time.thread_time() - cpu
            _plans.append((started, time.perf_counter()))
    return timed


def _marked(what: str, function):
    def marked(*args, **kwargs):
        started = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            _marks.append((what, started, time.perf_counter()))
    return marked


def _write(*_) -> None:
    folder = os.environ["ADVPERC_PLAN_TIMER"]
    path = os.path.join(folder, f"{os.getpid()}.json")
    with open(path + ".part", "w") as out:
        json.dump({"calls": _tally[0], "seconds": _tally[1], "plans": _plans, "marks": _marks}, out)
    os.replace(path + ".part", path)
    forget()


def _mark_publishes() -> None:
    from advperc_ros.ros import dds, transport
    for publication in (dds.Publication, transport._RclpyPublication):
        publish = publication.publish
        publication.publish = lambda self, msg, publish=publish: _marked(
            "publish " + getattr(self, "topic", getattr(getattr(self, "_publisher", None), "topic_name", "?")),
            publish)(self, msg)


def _install() -> None:
    from advperc_ros.core.planners.idm import IDMPlanner
    from advperc_ros.core.planners.obp.planner import OBPPlanner
    from advperc_ros.nodes import runtime
    for planner in (IDMPlanner, OBPPlanner):
        planner.plan = _timed(planner.plan)
    run_node = runtime.run_node

    def run_marked_node(spec, args=None):
        main = sys.modules["__main__"]
        for name, methods in NODE_ENTRIES.items():
            node = getattr(main, name, None)
            for method in methods if node is not None else ():
                setattr(node, method, _marked(method, getattr(node, method)))
        return run_node(spec, args)

    runtime.run_node = run_marked_node
    _mark_publishes()
    if os.environ.get("ADVPERC_PLAN_TIMER"):
        signal.signal(signal.SIGUSR1, _write)


with contextlib.suppress(ImportError):  # an interpreter without the package on its path: nothing to time
    _install()
