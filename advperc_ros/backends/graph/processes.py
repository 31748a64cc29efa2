"""The graph's node processes: started as children, watched, stopped.

Without ROS each child is a bare Cyclone DDS node given the params the orchestrator validated (as
JSON, `--params-json`) and `--exit-with-parent`. Under an rclpy orchestrator (`ros2 run advperc_ros
orchestrator`) each is the rclpy node `ros2 run advperc_ros <node>` starts, named as under the launch
file and given the same parameters the launch file gives it, so `ros2 node list` and `ros2 param`
see the whole graph; the kernel ends it when this process dies (PR_SET_PDEATHSIG). Either way none
outlives this process, and its output goes to a log file whose tail is quoted when it dies.
"""

import ctypes
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

from advperc_ros.nodes.graph_nodes import SPECS
from advperc_ros.nodes.runtime import node_environment

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


PR_SET_PDEATHSIG = 1  # prctl(2): the signal a child gets when its parent dies


def _die_with_parent() -> None:
    """In the child before exec: SIGTERM when the starting process dies (an rclpy node has no
    --exit-with-parent flag of ours)."""
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def how_it_ended(returncode: int) -> str:
    """A child's end as a person reads it: Popen gives a signal as a negative return code."""
    if returncode < 0:
        try:
            return f"was killed by signal {signal.Signals(-returncode).name}"
        except ValueError:
            return f"was killed by signal {-returncode}"
    return f"exited with code {returncode}"


class NodeProcesses:
    """The five graph nodes as child processes (none until `start`), with their logs. `ros_parameters`
    (node name -> its ROS parameters) makes them rclpy nodes, on the starting rclpy node's domain
    (ROS_DOMAIN_ID, inherited); without it they are bare Cyclone nodes on `domain_id`."""

    def __init__(self, params_json: str, domain_id: int, localhost_only: bool, partition: str,
                 ros_parameters: dict[str, dict[str, Any]] | None = None) -> None:
        remove_stale_workdirs()
        self._workdir = tempfile.TemporaryDirectory(prefix=f"{WORKDIR_PREFIX}{os.getpid()}-")
        self._commands = {name: [sys.executable, "-m", f"advperc_ros.nodes.{name}", *self._arguments(
            name, params_json, domain_id, localhost_only, partition, ros_parameters)] for name in NODES}
        self._ros = ros_parameters is not None
        # an rclpy node reads its DDS configuration before its parameters: what the clock drive's need, given here
        self._environments = {spec.name: node_environment(spec, ros_parameters[spec.name]) if ros_parameters else {}
                              for spec in SPECS}
        self.running: dict[str, subprocess.Popen] = {}

    def _arguments(self, name: str, params_json: str, domain_id: int, localhost_only: bool, partition: str,
                   ros_parameters: dict[str, dict[str, Any]] | None) -> list[str]:
        if ros_parameters is None:
            return ["--params-json", params_json, "--domain-id", str(domain_id), "--partition", partition,
                    "--localhost-only", "true" if localhost_only else "false", "--exit-with-parent"]
        path = Path(self._workdir.name) / f"{name}.yaml"
        path.write_text(yaml.safe_dump({name: {"ros__parameters": ros_parameters[name]}}))
        return ["--ros-args", "-r", f"__node:={name}", "--params-file", str(path)]

    def start(self) -> None:
        root = str(Path(__file__).resolve().parents[3])
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p))
        for name in NODES:
            with (Path(self._workdir.name) / f"{name}.log").open("ab") as output:
                self.running[name] = subprocess.Popen(
                    self._commands[name], stdin=subprocess.DEVNULL, stdout=output, stderr=subprocess.STDOUT,
                    env={**env, **self._environments[name]},
                    preexec_fn=_die_with_parent if self._ros else None)

    def dead(self) -> str | None:
        """What went wrong if a child has exited, else None."""
        for name, process in self.running.items():
            code = process.poll()
            if code is not None:
                return f"the {name} process {how_it_ended(code)}{self._log_tail(name)}"
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
