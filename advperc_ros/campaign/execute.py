"""Running cells: what one cell does, wherever it runs, and the executors that run them.

Every executor runs the same `run_cell`, which writes the cell's folder atomically (attack_to_folder,
write_replay) and answers a `CellResult`; a cell's result depends on its params and seed only, so
every executor gives the same table. Each cell builds its own stack: a fresh planner per cell is
what keeps results independent of which worker ran what before (it costs 3 ms for IDM, 0.2-0.5 s
for ObP, against seconds to minutes of search). The campaign keeps as many cells in flight as it
has workers, so it always knows which cells are running.
"""

import os
import sys
import traceback
from collections import deque
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Protocol

from advperc_ros.application import attack_to_folder
from advperc_ros.campaign.spec import Campaign, Cell
from advperc_ros.exits import EXPECTED_TYPES, expected_failure
from advperc_ros.params import ParamsError
from advperc_ros.replay import load_attack, replay, write_replay


@dataclass(frozen=True)
class CellResult:
    name: str
    error: str | None = None  # the one-line expected failure, or a bug's traceback
    exit_code: int | None = None  # of an expected failure; None for a bug


def run_cell(cell: Cell, output: Path, progress: bool = False) -> CellResult:
    """Attack (or replay) one cell into output/<cell name>; an expected failure is the cell's result,
    not the campaign's end. An attack a kill interrupted resumes from its checkpoint, so it costs
    only the rollouts it had not run."""
    folder = output / cell.name
    try:
        if cell.attack is None:
            # a killed cell goes on from its checkpoint
            attack_to_folder(cell.params, folder, progress=progress, resume=True)
        else:
            write_replay(folder, replay(load_attack(cell.attack), cell.params))
    except EXPECTED_TYPES as exc:
        line, code = expected_failure(exc)
        return CellResult(cell.name, line, code)
    except Exception:  # a bug: its traceback goes into the summary, and the other cells go on
        return CellResult(cell.name, traceback.format_exc())
    return CellResult(cell.name)


class Executor(Protocol):
    """Runs submitted cells; `next_done` blocks until one has finished."""

    def submit(self, cell: Cell) -> None: ...

    def next_done(self) -> CellResult: ...

    def close(self) -> None: ...


class SerialExecutor:
    """In this process, one cell at a time, each with its rollout progress bar."""

    def __init__(self, output: Path, progress: bool) -> None:
        self.output, self.progress = output, progress
        self.queue: deque[Cell] = deque()

    def submit(self, cell: Cell) -> None:
        self.queue.append(cell)

    def next_done(self) -> CellResult:
        return run_cell(self.queue.popleft(), self.output, self.progress)

    def close(self) -> None:
        self.queue.clear()


def _die_with_the_campaign() -> None:
    """Worker initializer: on Linux, the kernel kills a worker whose campaign dies, so a killed campaign
    leaves no worker writing into its folder while a restarted one runs the same cell."""
    if sys.platform == "linux":
        import ctypes
        import signal

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
        if os.getppid() == 1:  # the campaign died before the line above
            os._exit(1)


class ProcessExecutor:
    """A pool of worker processes, started fresh (spawn) rather than forked from a process that has
    loaded everything. A worker that dies under its cell (killed from outside, out of memory, a crash
    in native code) takes the pool with it: a fresh pool runs each cell lost so once more, and a cell
    lost twice is that cell's error, so the other cells go on."""

    def __init__(self, output: Path, workers: int) -> None:
        self.output, self.workers = output, workers
        self.pool = self._pool()
        self.futures: dict[Future, Cell] = {}
        self.lost: set[str] = set()  # cells a dead pool took once
        self.failed: deque[CellResult] = deque()  # cells it took twice

    def _pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(self.workers, mp_context=get_context("spawn"), initializer=_die_with_the_campaign)

    def submit(self, cell: Cell) -> None:
        self.futures[self.pool.submit(run_cell, cell, self.output)] = cell

    def next_done(self) -> CellResult:
        while not self.failed:
            done, _ = wait(self.futures, return_when=FIRST_COMPLETED)
            future = done.pop()
            cell = self.futures.pop(future)
            try:
                return future.result()
            except BrokenProcessPool:
                self._replace_pool([cell, *self.futures.values()])
        return self.failed.popleft()

    def _replace_pool(self, lost: list[Cell]) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)
        self.futures.clear()
        self.pool = self._pool()
        for cell in lost:
            if cell.name in self.lost:
                self.failed.append(CellResult(cell.name, "its worker process died twice under it (killed from outside, "
                                              "out of memory, or a crash in native code)"))
            else:
                self.lost.add(cell.name)
                self.submit(cell)

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)


LOOPBACK = "127.0.0.1"
SINGLE_NODE = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"  # "0": ray gives its node the loopback address
LOCAL_RAY = {SINGLE_NODE: "0",
             "RAY_worker_niceness": "0"}  # ray's 15 would leave its cells behind every other process on a shared machine


class RayExecutor:
    """Ray tasks. Without an address, a local Ray of `workers` CPUs on the loopback interface only:
    Ray takes this machine's network address for its node unless told the node is not part of a
    cluster (RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0, read when ray is imported), with no dashboard and no
    usage statistics sent; its workers run at the campaign's priority and import this very
    advperc_ros. With an address, the cluster's nodes need advperc_ros installed and the campaign's
    files (bags, output) at the same paths."""

    def __init__(self, output: Path, workers: int, address: str | None) -> None:
        if address is None and "ray" in sys.modules and os.environ.get(SINGLE_NODE) != LOCAL_RAY[SINGLE_NODE]:
            raise ParamsError("executor ray: ray was imported before the campaign could keep a local Ray on "
                              f"{LOOPBACK}; run the campaign in a fresh process")
        os.environ["RAY_USAGE_STATS_ENABLED"] = "0"
        if address is None:
            os.environ.update(LOCAL_RAY)
        import logging

        import ray

        import advperc_ros

        if address is None:
            package_root = str(Path(advperc_ros.__file__).resolve().parent.parent)
            path = os.pathsep.join(p for p in (package_root, os.environ.get("PYTHONPATH")) if p)
            ray.init(num_cpus=workers, include_dashboard=False, logging_level=logging.ERROR, log_to_driver=False,
                     runtime_env={"env_vars": {"PYTHONPATH": path}})
            if ray.util.get_node_ip_address() != LOOPBACK:
                node = ray.util.get_node_ip_address()
                ray.shutdown()
                raise ParamsError(f"executor ray: the local Ray took address {node}, not {LOOPBACK}")
        else:
            ray.init(address=address, include_dashboard=False, logging_level=logging.ERROR, log_to_driver=False)
        self.ray, self.output = ray, output
        self.task = ray.remote(num_cpus=1, max_retries=0)(run_cell)
        self.refs: dict = {}  # task -> cell name

    def submit(self, cell: Cell) -> None:
        self.refs[self.task.remote(cell, self.output)] = cell.name

    def next_done(self) -> CellResult:
        (done,), _ = self.ray.wait(list(self.refs), num_returns=1)
        name = self.refs.pop(done)
        try:
            return self.ray.get(done)
        except self.ray.exceptions.RayError:  # the worker died under the cell (killed, out of memory)
            return CellResult(name, traceback.format_exc())

    def close(self) -> None:
        for ref in self.refs:
            self.ray.cancel(ref, force=True)
        self.ray.shutdown()


def executor(campaign: Campaign, output: Path, progress: bool) -> Executor:
    if campaign.executor == "serial":
        return SerialExecutor(output, progress)
    if campaign.executor == "process":
        return ProcessExecutor(output, campaign.workers)
    return RayExecutor(output, campaign.workers, campaign.ray_address)
