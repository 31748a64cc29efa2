"""What the five graph nodes share: how they start, take parameters, tell rollouts apart and stop.

Every node module has a `main(args=None)` that calls `run_node` with its `NodeSpec`. The same
executable runs two ways:

- with ROS 2 (`ros2 run advperc_ros tracker --ros-args ...`, or launch/attack.launch.py): an rclpy
  node with its parameters declared with types and descriptions, spun until shutdown;
- without ROS (`tracker --params-file P.yaml --domain-id 42 --localhost-only true`): a Cyclone DDS
  participant speaking ROS 2's wire conventions, parameters read from an orchestrator params file.
  This is how `advperc_ros.graph.GraphRollouts` starts the graph as separate OS processes.

The Cyclone path is taken when rclpy is missing or the arguments are our own flags (no
`--ros-args`), so a machine with ROS 2 sourced can run both.
"""

import argparse
import functools
import logging
import os
import signal
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from advperc_ros.core.planners.base import PlannerError
from advperc_ros.core.scenario import ScenarioError
from advperc_ros.params import PLANNER_PARAMS, SCHEMA, ParamsError, load_params, node_values, parse_planner_params
from advperc_ros.ros import cdr
from advperc_ros.ros.bag import GROUND_TRUTH, BagError
from advperc_ros.ros.lockstep import CONTROL_TYPE, PRESENCE, presence_message
from advperc_ros.ros.transport import Transport

INPUT_ERRORS = (ParamsError, BagError, ScenarioError, PlannerError)  # as the CLI's, without importing it
POLL_PERIOD = 0.05  # s between `poll()` calls of a node that has one (the player's timeouts)
GROUND_TRUTH_CACHE = 4096  # distinct /ground_truth/objects messages kept decoded
EXIT_INPUT = 2


class Logger(Protocol):
    """Python's logging.Logger and rclpy's node logger both fit."""

    def info(self, message: str) -> None: ...

    def warning(self, message: str) -> None: ...

    def error(self, message: str) -> None: ...


@dataclass(frozen=True)
class NodeSpec:
    """A graph node: its ROS name, the params.SCHEMA names it declares, and how its logic is built
    from a transport, those values (`bag` resolved to a path), the planner's params and a logger."""

    name: str
    params: tuple[str, ...]
    build: Callable[[Transport, dict[str, Any], dict[str, Any], Logger], object]
    planner_params: bool = False  # declares `planner_params` too


class RolloutClock:
    """Tells rollouts apart from stamps alone, so a node needs no control topic and an external
    planner can follow the same rule: an input stamped at or before the last answered stamp
    starts a new rollout (every rollout starts again at the scenario's first stamp, and the
    player never publishes frame k+1 before frame k is answered). Times are counted from the
    rollout's first stamp, exactly as `Scenario.times` counts them."""

    def __init__(self) -> None:
        self._origin = 0
        self._answered: int | None = None
        self._fresh = True

    def observe(self, stamp: int) -> bool:
        """Call on every input; True when it begins a new rollout (inputs still pending from
        the previous one must then be dropped)."""
        if self._answered is not None and stamp <= self._answered:
            self._answered = None
            self._fresh = True
            return True
        return False

    def answer(self, stamp: int) -> tuple[bool, float]:
        """Call when answering the input(s) stamped `stamp`: (first answer of a rollout, so reset
        the core object; seconds since the rollout's first stamp)."""
        first = self._fresh
        if first:
            self._origin = stamp
            self._fresh = False
        self._answered = stamp
        return first, (stamp - self._origin) * 1e-9


class StampPairs:
    """Pairs two input streams (`put(0, ...)`, `put(1, ...)`) by stamp and calls `answer(stamp,
    first, second)` once both are in; what is still unpaired when a new rollout starts is dropped."""

    def __init__(self, answer: Callable[[int, Any, Any], None]) -> None:
        self.clock = RolloutClock()
        self._answer = answer
        self._pending: tuple[dict[int, Any], dict[int, Any]] = ({}, {})

    def put(self, stream: int, stamp: int, value: Any) -> None:
        if self.clock.observe(stamp):
            for pending in self._pending:
                pending.clear()
        self._pending[stream][stamp] = value
        if all(stamp in pending for pending in self._pending):
            first, second = (pending.pop(stamp) for pending in self._pending)
            self._answer(stamp, first, second)


@functools.lru_cache(maxsize=GROUND_TRUTH_CACHE)
def _ground_truth(data: bytes) -> tuple[int | None, dict[str, np.ndarray]]:
    stamp, objects = cdr.decode_objects(data, GROUND_TRUTH)
    for values in objects.values():
        values.flags.writeable = False  # shared by every call with these bytes
    return stamp, objects


def ground_truth_objects(data: bytes) -> tuple[int | None, dict[str, np.ndarray]]:
    """A /ground_truth/objects payload as `cdr.decode_objects` reads it, each distinct payload
    decoded once: the player sends the bag's own bytes in every rollout, so a search would decode
    the same few hundred messages again and again. The arrays are read-only (they are shared)."""
    stamp, objects = _ground_truth(data)
    return stamp, dict(objects)


def announce(transport: Transport, name: str) -> None:
    """Say on the latched /attack/nodes that this node is up with all its topics created; the
    graph backend waits for every node it started before its warm-up rollout."""
    transport.publisher(PRESENCE, CONTROL_TYPE, latched=True).publish(presence_message(name, os.getpid()))


def run_node(spec: NodeSpec, args: list[str] | None = None) -> int:
    """Run the node until shutdown (SIGINT, SIGTERM, ROS shutdown); the process exit code."""
    argv = sys.argv[1:] if args is None else list(args)
    if "--ros-args" in argv or not argv:
        try:
            import rclpy  # noqa: F401
        except ImportError:
            if "--ros-args" in argv:
                print(f"{spec.name}: --ros-args given but rclpy is not found; source ROS 2 Jazzy, or run "
                      f"`{spec.name} --params-file PARAMS.yaml` (Cyclone DDS, no ROS)", file=sys.stderr)
                return EXIT_INPUT
        else:
            return _run_rclpy(spec, args)
    return _run_cyclone(spec, argv)


def _resolve(values: dict[str, Any], source: Path | None) -> dict[str, Any]:
    """`bag` as a path, found as `advperc attack` finds it."""
    if "bag" in values:
        from advperc_ros.attack import find_bag

        values["bag"] = find_bag(values["bag"], source)
    return values


_ROS_TYPES = {str: "STRING", float: "DOUBLE", int: "INTEGER", bool: "BOOL"}


def _run_rclpy(spec: NodeSpec, args: list[str] | None) -> int:
    import rclpy
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.exceptions import InvalidParameterTypeException, ParameterUninitializedException
    from rclpy.executors import ExternalShutdownException
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from advperc_ros.ros.transport import RclpyTransport

    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = Node(spec.name)
        where = f"node '{spec.name}' parameters"
        flat: dict[str, Any] = {}
        try:
            for name in spec.params:
                param = SCHEMA[name]
                kind = getattr(Parameter.Type, _ROS_TYPES[param.type])
                descriptor = ParameterDescriptor(description=param.description, type=kind.value)
                node.declare_parameter(name, kind if param.default is None else param.default, descriptor)
                try:
                    flat[name] = node.get_parameter(name).value
                except ParameterUninitializedException:
                    flat[name] = None
            planner_params: dict[str, Any] = {}
            if spec.planner_params:
                descriptor = ParameterDescriptor(description="keyword arguments of the planner's constructor, "
                                                 "as one YAML mapping, e.g. '{target_speed: 14.0}'",
                                                 type=Parameter.Type.STRING.value)
                text = node.declare_parameter(PLANNER_PARAMS, "{}", descriptor).value
                planner_params = parse_planner_params(where, text)
            values = _resolve(node_values(flat, spec.params, where), None)
            transport = RclpyTransport(node)
            logic = spec.build(transport, values, planner_params, node.get_logger())
            announce(transport, spec.name)
        except InvalidParameterTypeException as exc:
            raise ParamsError(f"{where}: {exc}") from exc
        poll = getattr(logic, "poll", None)
        if poll is not None:
            node.create_timer(POLL_PERIOD, poll)
        rclpy.spin(node)
    except INPUT_ERRORS as exc:
        if node is not None:
            node.get_logger().error(str(exc))
        code = EXIT_INPUT
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


def _flag(text: str) -> bool:
    if text not in ("true", "false"):
        raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")
    return text == "true"


def _run_cyclone(spec: NodeSpec, argv: list[str]) -> int:
    from advperc_ros.ros.dds import DdsError, DdsTransport

    parser = argparse.ArgumentParser(
        prog=spec.name, description=f"advperc_ros graph node '{spec.name}' over Cyclone DDS (no ROS needed).")
    parser.add_argument("--params-file", required=True, help="orchestrator params YAML (as for `advperc attack`)")
    parser.add_argument("--domain-id", type=int, help="DDS domain id (default: the file's dds.domain_id)")
    parser.add_argument("--localhost-only", type=_flag, help="true|false (default: the file's dds.localhost_only)")
    parser.add_argument("--exit-with-parent", action="store_true",
                        help="exit when the starting process dies (the graph backend sets it: no orphans)")
    options = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format=f"[{spec.name}] %(levelname)s: %(message)s")
    logger = logging.getLogger(spec.name)
    try:
        params = load_params(options.params_file)
        values = _resolve({name: params[name] for name in spec.params}, params.source)
        domain_id = params["dds.domain_id"] if options.domain_id is None else options.domain_id
        localhost_only = params["dds.localhost_only"] if options.localhost_only is None else options.localhost_only
        transport = DdsTransport(domain_id, localhost_only)
    except (*INPUT_ERRORS, DdsError) as exc:
        logger.error(str(exc))
        return EXIT_INPUT
    stopping: list[int] = []
    signal.signal(signal.SIGTERM, lambda signum, frame: stopping.append(signum))
    parent = os.getppid()
    try:
        with transport:
            logic = spec.build(transport, values, params.planner_params, logger)
            announce(transport, spec.name)
            poll = getattr(logic, "poll", None)
            logger.info(f"running on DDS domain {domain_id}" + (" (localhost only)" if localhost_only else ""))
            while not stopping and not (options.exit_with_parent and os.getppid() != parent):
                transport.spin_once(POLL_PERIOD)
                if poll is not None:
                    poll()
    except INPUT_ERRORS as exc:
        logger.error(str(exc))
        return EXIT_INPUT
    except KeyboardInterrupt:
        pass
    return 0
