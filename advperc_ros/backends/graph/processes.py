"""The graph's node processes: started as children over Cyclone DDS, watched, stopped.

Each child gets the params the orchestrator validated (as JSON, `--params-json`) and
`--exit-with-parent`, so none outlives this process; its output goes to a log file whose tail is
quoted when it dies.
"""

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from advperc_ros.nodes.graph_nodes import SPECS

STOP_TIMEOUT = 5.0  # s between SIGTERM and SIGKILL on shutdown
LOG_TAIL = 5  # lines of a dead child's log quoted in the error
NODES = tuple(spec.name for spec in SPECS)
WORKDIR_PREFIX = "advperc-graph-"  # + the starting process's pid: a folder whose process is gone is stale


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def remove_stale_workdirs() -> None:
    """Remove the log folders of graphs whose starting process was killed (SIGKILL leaves them)."""
    for folder in Path(tempfile.gettempdir()).glob(f"{WORKDIR_PREFIX}*-*"):
        pid = folder.name[len(WORKDIR_PREFIX):].split("-")[0]
        if pid.isdigit() and not _alive(int(pid)):
            shutil.rmtree(folder, ignore_errors=True)


class NodeProcesses:
    """The five graph nodes as child processes (none until `start`), with their logs."""

    def __init__(self, params_json: str, domain_id: int, localhost_only: bool, partition: str) -> None:
        remove_stale_workdirs()
        self._workdir = tempfile.TemporaryDirectory(prefix=f"{WORKDIR_PREFIX}{os.getpid()}-")
        self._flags = ["--params-json", params_json, "--domain-id", str(domain_id), "--partition", partition,
                       "--localhost-only", "true" if localhost_only else "false", "--exit-with-parent"]
        self.running: dict[str, subprocess.Popen] = {}

    def start(self) -> None:
        root = str(Path(__file__).resolve().parents[3])
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p))
        for name in NODES:
            with (Path(self._workdir.name) / f"{name}.log").open("ab") as output:
                self.running[name] = subprocess.Popen(
                    [sys.executable, "-m", f"advperc_ros.nodes.{name}", *self._flags],
                    stdin=subprocess.DEVNULL, stdout=output, stderr=subprocess.STDOUT, env=env)

    def dead(self) -> str | None:
        """What went wrong if a child has exited, else None."""
        for name, process in self.running.items():
            code = process.poll()
            if code is not None:
                return f"the {name} process exited with code {code}{self._log_tail(name)}"
        return None

    def _log_tail(self, name: str) -> str:
        path = Path(self._workdir.name) / f"{name}.log"
        lines = path.read_text(errors="replace").strip().splitlines()[-LOG_TAIL:] if path.exists() else []
        return "; its last log lines: " + " | ".join(lines) if lines else ""

    def stop(self, kill: bool) -> None:
        """SIGKILL (`kill`) or SIGTERM every child, SIGKILL after `STOP_TIMEOUT`, and wait for them."""
        for process in self.running.values():
            if process.poll() is None:
                process.send_signal(signal.SIGKILL if kill else signal.SIGTERM)
        deadline = time.monotonic() + STOP_TIMEOUT
        for process in self.running.values():
            try:
                process.wait(max(deadline - time.monotonic(), 0.0))
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        self.running.clear()

    def close(self) -> None:
        """Stop the children and remove their logs; idempotent."""
        self.stop(kill=False)
        self._workdir.cleanup()
