"""Running cells: what one cell does, wherever it runs, and the executors that run them.

Every executor runs the same `run_cell`, which writes the cell's folder atomically (attack_to_folder,
write_replay) and answers a `CellResult`; a cell's result depends on its params and seed only, so
every executor gives the same table. Each cell builds its own stack: a fresh planner per cell is
what keeps results independent of which worker ran what before (it costs 3 ms for IDM, 0.2-0.5 s
for ObP, against seconds to minutes of search). The campaign keeps as many cells in flight as it
has workers, so it always knows which cells are running.

Ray's workers may be on machines that share no file system with the campaign (a KubeRay cluster, a
few cloud VMs), so the Ray executor sends each cell its inputs through Ray (the bag once per bag into
the object store; a replayed attack's report and errors with the task), the worker runs the cell in a
temporary folder of its own (`run_shipped_cell`), and the results folder's files come back to the
campaign, which alone writes the output.
"""

import os
import re
import sys
import tempfile
import traceback
from collections import deque
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import ExitStack, redirect_stdout, suppress
from dataclasses import dataclass, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Protocol

from advperc_ros.application import attack_to_folder
from advperc_ros.campaign.spec import Campaign, Cell
from advperc_ros.core.staging import staged_folder
from advperc_ros.exceptions import ParamsError
from advperc_ros.exits import EXPECTED_TYPES, expected_failure
from advperc_ros.heap import keep_freed_heap
from advperc_ros.params import resolve_bag
from advperc_ros.replay import load_attack, replay, write_replay
from advperc_ros.results.destination import check_output
from advperc_ros.results.folder import ERRORS, REPORT_JSON


@dataclass(frozen=True)
class CellResult:
    """How one cell ended in its worker: an error is that cell's, never the campaign's, so one bad
    scenario cannot cost the other cells their results."""

    name: str
    error: str | None = None  # the one-line expected failure, or a bug's traceback
    exit_code: int | None = None  # of an expected failure; None for a bug
    peak_rss_mib: float | None = None  # the worker's peak resident memory while it ran the cell (Linux only)


def _outcome(name: str, work: Callable[[], object]) -> CellResult:
    """`work` done as a cell's: an expected failure is the cell's result, not the campaign's end, and a
    bug's traceback goes into the summary while the other cells go on."""
    try:
        work()
    except EXPECTED_TYPES as exc:
        line, code = expected_failure(exc)
        return CellResult(name, line, code)
    except Exception:
        return CellResult(name, traceback.format_exc())
    return CellResult(name)


PROC_SELF = Path("/proc/self")


def _reset_peak_memory() -> None:
    """Linux lets a process set its peak resident memory (VmHWM) back to what it holds now, so a worker
    that ran other cells before measures this cell alone (its Python and imports included)."""
    with suppress(OSError):  # not Linux
        (PROC_SELF / "clear_refs").write_text("5")


def _peak_memory_mib() -> float | None:
    try:
        found = re.search(r"^VmHWM:\s+(\d+) kB", (PROC_SELF / "status").read_text(), re.MULTILINE)
    except OSError:  # not Linux
        return None
    return round(int(found.group(1)) / 1024, 1) if found else None


def run_cell(cell: Cell, output: Path, progress: bool = False, bag: Path | None = None,
             attack: Path | None = None) -> CellResult:
    """Attack (or replay) one cell into output/<cell name>, measuring the worker's peak memory. An attack
    a kill interrupted resumes from its checkpoint, so it costs only the rollouts it had not run. `bag`
    and `attack`: local copies of the cell's bag and replayed results folder (a Ray worker's), used
    instead of the paths the cell names, which the report and summary still name."""
    keep_freed_heap()
    folder = output / cell.name

    def work() -> None:
        if cell.attack is None:
            # a killed cell goes on from its checkpoint
            attack_to_folder(cell.params, folder, progress=progress, resume=True, bag_path=bag)
        else:
            found = replace(load_attack(attack or cell.attack), folder=cell.attack)
            write_replay(folder, replay(found, cell.params, bag))

    _reset_peak_memory()
    return replace(_outcome(cell.name, work), peak_rss_mib=_peak_memory_mib())


@dataclass(frozen=True)
class Shipped:
    """A file or a folder as bytes: how a cell's inputs reach a Ray worker, and its results folder the
    campaign, when they share no file system."""

    name: str  # the file's or folder's own name (a bag reader may go by its suffix)
    files: tuple[tuple[str, bytes], ...]  # (path in the folder, bytes); a file is one entry with path ""

    @classmethod
    def of(cls, path: Path, only: tuple[str, ...] | None = None) -> "Shipped":
        """The file, or the folder's files (those named `only`, when given), in a stable order."""
        if path.is_file():
            return cls(path.name, (("", path.read_bytes()),))
        files = sorted(p for p in path.rglob("*") if p.is_file() and (only is None or p.name in only))
        return cls(path.name, tuple((p.relative_to(path).as_posix(), p.read_bytes()) for p in files))

    def write(self, path: Path) -> Path:
        """Recreate it as `path`, which is returned."""
        if len(self.files) == 1 and self.files[0][0] == "":
            path.write_bytes(self.files[0][1])
            return path
        path.mkdir()
        for name, data in self.files:
            (path / name).parent.mkdir(parents=True, exist_ok=True)
            (path / name).write_bytes(data)
        return path


def shipped_attack(cell: Cell) -> Shipped | None:
    """What a replay cell's worker needs of the attack replayed: what load_attack reads of its folder."""
    return Shipped.of(cell.attack, only=(REPORT_JSON, ERRORS)) if cell.attack is not None else None


def run_shipped_cell(cell: Cell, bag: Shipped, attack: Shipped | None) -> tuple[CellResult, Shipped | None]:
    """A cell on a Ray worker, which may see none of the campaign's paths: in a temporary folder of its
    own, from the inputs that came with it (the cell's params travel in the cell as values); answers
    the result and the results folder's files, for the campaign to write."""
    with tempfile.TemporaryDirectory(prefix="advperc-cell-") as temporary:
        root = Path(temporary)
        (root / "inputs").mkdir()
        result = run_cell(cell, root / "output", bag=bag.write(root / "inputs" / bag.name),
                          attack=attack.write(root / "inputs" / "attack") if attack is not None else None)
        folder = root / "output" / cell.name
        return result, Shipped.of(folder) if folder.is_dir() else None


def place(output: Path, result: CellResult, folder: Shipped | None) -> CellResult:
    """The cell's results folder, written by the campaign as a worker on its machine would have: into a
    staging folder renamed into place, so a kill leaves only what the next run clears."""
    if folder is None:
        return result

    def work() -> None:
        check_output(output / result.name)  # what attack_to_folder refuses there
        with staged_folder(output / result.name) as staging:
            folder.write(staging)

    placed = _outcome(result.name, work)
    return result if placed.error is None else replace(placed, peak_rss_mib=result.peak_rss_mib)


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
    lost twice is that cell's error, so the other cells go on. A cell whose results folder was in place
    when its worker died (killed between the folder's rename and its answer) is finished, not lost."""

    def __init__(self, output: Path, workers: int) -> None:
        self.output, self.workers = output, workers
        self.pool = self._pool()
        self.futures: dict[Future, Cell] = {}
        self.lost: set[str] = set()  # cells a dead pool took once
        self.settled: deque[CellResult] = deque()  # cells it took twice, or took once they had finished

    def _pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(self.workers, mp_context=get_context("spawn"), initializer=_die_with_the_campaign)

    def submit(self, cell: Cell) -> None:
        self.futures[self.pool.submit(run_cell, cell, self.output)] = cell

    def next_done(self) -> CellResult:
        while not self.settled:
            done, _ = wait(self.futures, return_when=FIRST_COMPLETED)
            future = done.pop()
            cell = self.futures.pop(future)
            try:
                return future.result()
            except BrokenProcessPool:
                self._replace_pool([cell, *self.futures.values()])
        return self.settled.popleft()

    def _replace_pool(self, lost: list[Cell]) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)
        self.futures.clear()
        self.pool = self._pool()
        for cell in lost:
            if cell.report(self.output) is not None:
                self.settled.append(CellResult(cell.name))
            elif cell.name in self.lost:
                self.settled.append(CellResult(cell.name, "its worker process died twice under it (killed from outside, "
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


RETRIES = 1  # a cell's Ray worker or node may die once under it; a second death is the cell's error, as in a pool


class RayExecutor:
    """Ray tasks, which share no file system with the campaign: each cell's bag goes once into the
    object store (shared by the cells of that bag), a replayed attack's report and errors go with its
    task, and the results folder comes back to be written here (`run_shipped_cell`, `place`). A task
    whose worker or node dies is run once more (Ray's retries); a second death is that cell's error.

    Without an address, a local Ray of `workers` CPUs on the loopback interface only: Ray takes this
    machine's network address for its node unless told the node is not part of a cluster
    (RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0, read when ray is imported), with no dashboard and no usage
    statistics sent; its workers run at the campaign's priority and import this very advperc_ros.
    With an address, the cluster's nodes need advperc_ros installed, and none of the campaign's paths."""

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

        with ExitStack() as stack:  # undone if Ray cannot start here
            # the campaign's stdout is its one-line summary, but Ray prints a cluster's errors (a node lost)
            # to the driver's stdout from a thread of its own: they go to stderr, beside the campaign's progress
            stack.enter_context(redirect_stdout(sys.stderr))
            if address is None:
                package_root = str(Path(advperc_ros.__file__).resolve().parent.parent)
                path = os.pathsep.join(p for p in (package_root, os.environ.get("PYTHONPATH")) if p)
                ray.init(num_cpus=workers, include_dashboard=False, logging_level=logging.ERROR, log_to_driver=False,
                         runtime_env={"env_vars": {"PYTHONPATH": path}})
            else:
                ray.init(address=address, include_dashboard=False, logging_level=logging.ERROR, log_to_driver=False)
            stack.callback(ray.shutdown)
            if address is None and ray.util.get_node_ip_address() != LOOPBACK:
                raise ParamsError(f"executor ray: the local Ray took address {ray.util.get_node_ip_address()}, "
                                  f"not {LOOPBACK}")
            self.stack = stack.pop_all()
        self.ray, self.output = ray, output
        self.task = ray.remote(num_cpus=1, max_retries=RETRIES)(run_shipped_cell)
        self.bags: dict[Path, object] = {}  # bag -> its object in the store
        self.refs: dict = {}  # task -> cell name

    def submit(self, cell: Cell) -> None:
        bag = resolve_bag(cell.params)  # checked by plan(): it exists here
        if bag not in self.bags:
            self.bags[bag] = self.ray.put(Shipped.of(bag))
        self.refs[self.task.remote(cell, self.bags[bag], shipped_attack(cell))] = cell.name

    def next_done(self) -> CellResult:
        (done,), _ = self.ray.wait(list(self.refs), num_returns=1)
        name = self.refs.pop(done)
        try:
            result, folder = self.ray.get(done)
        except self.ray.exceptions.RayTaskError:  # raised on the worker outside the cell (its temporary folder)
            return CellResult(name, traceback.format_exc())
        except self.ray.exceptions.RayError as exc:  # its worker or node died under it, and again under its retry
            return CellResult(name, f"its Ray worker died twice under it (its node lost, killed from outside, or out "
                                    f"of memory): {type(exc).__name__}")
        return place(self.output, result, folder)

    def close(self) -> None:
        for ref in self.refs:
            self.ray.cancel(ref, force=True)
        self.stack.close()  # Ray shut down, then stdout back


def executor(campaign: Campaign, output: Path, progress: bool) -> Executor:
    return make_executor(campaign.executor, output, progress, campaign.workers, campaign.ray_address)


def make_executor(kind: str, output: Path, progress: bool, workers: int, ray_address: str | None = None) -> Executor:
    """The executor `kind` (serial, process or ray) writing cells into `output`: a campaign's, or any other
    run of many attacks (`advperc requirements`)."""
    if kind == "serial":
        return SerialExecutor(output, progress)
    if kind == "process":
        return ProcessExecutor(output, workers)
    return RayExecutor(output, workers, ray_address)
