"""Loaded by every interpreter that has this folder on its path (planner_process_cost.py puts it on
the graph nodes' PYTHONPATH): wraps the planner classes' `plan` so that each call's thread CPU time is
tallied, and, where ADVPERC_PLAN_TIMER names a folder, writes (calls, seconds) to `<pid>.json` there
on SIGUSR1. Benchmark-only: nothing in the package loads it."""

import contextlib
import json
import os
import signal
import time

_tally = [0, 0.0]


def tally() -> tuple[int, float]:
    """(plan() calls, their thread CPU seconds) in this process so far."""
    return _tally[0], _tally[1]


def _timed(plan):
    def timed(self, *args, **kwargs):
        started = time.thread_time()
        try:
            return plan(self, *args, **kwargs)
        finally:
            _tally[0] += 1
            _tally[1] += time.thread_time() - started
    return timed


def _write(*_) -> None:
    folder = os.environ["ADVPERC_PLAN_TIMER"]
    path = os.path.join(folder, f"{os.getpid()}.json")
    with open(path + ".part", "w") as out:
        json.dump(_tally, out)
    os.replace(path + ".part", path)


def _install() -> None:
    from advperc_ros.core.planners.idm import IDMPlanner
    from advperc_ros.core.planners.obp.planner import OBPPlanner
    for planner in (IDMPlanner, OBPPlanner):
        planner.plan = _timed(planner.plan)
    if os.environ.get("ADVPERC_PLAN_TIMER"):
        signal.signal(signal.SIGUSR1, _write)


with contextlib.suppress(ImportError):  # an interpreter without the package on its path: nothing to time
    _install()
