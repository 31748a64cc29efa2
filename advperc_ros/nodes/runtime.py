"""What the five graph nodes share: how they start, take parameters, tell rollouts apart and stop.

Every node module has a `main(args=None)` that calls `run_node` with its `NodeSpec`. The same
executable runs two ways:

- with ROS 2 (`ros2 run advperc_ros tracker --ros-args ...`, or launch/attack.launch.py): an rclpy
  node holding every parameter it is given, checked as strictly as a params file (a name it does
  not take is refused), the rest declared with defaults and descriptions, spun until shutdown;
- without ROS (`tracker --params-file P.yaml --domain-id 42 --localhost-only true`): a Cyclone DDS
  participant speaking ROS 2's wire conventions, parameters read from an orchestrator params file.
  This is how `advperc_ros.backends.graph.rollouts.GraphRollouts` starts the graph as separate OS processes.

The Cyclone path is taken when rclpy is missing or the arguments are our own flags (no
`--ros-args`), so a machine with ROS 2 sourced can run both.
"""

import argparse
import functools
import itertools
import json
import logging
import os
import re
import signal
import sys
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import yaml

from advperc_ros.exits import EXIT_INPUT, EXIT_INTERRUPTED, EXPECTED_TYPES, INPUT_ERRORS, expected_failure
from advperc_ros.heap import keep_freed_heap
from advperc_ros.params import SCHEMA, find_bag, load_params, node_values, params_from_values
from advperc_ros.ros import cdr
from advperc_ros.ros.lockstep import presence_message
from advperc_ros.ros.topics import CONTROL_TYPE, GROUND_TRUTH, PRESENCE, PROMPT_HEARTBEATS, with_prompt_heartbeats
from advperc_ros.ros.transport import Transport

POLL_PERIOD = 0.05  # s between `poll()` calls of a node that has one (the player's timeouts)
GROUND_TRUTH_CACHE = 4096  # distinct /ground_truth/objects messages kept decoded


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
    waits_for_acks: bool = False  # (drive: clock) waits for every reader's acknowledgement of a frame


def prompt_heartbeats(spec: NodeSpec, values: Mapping[str, Any]) -> bool:
    """Whether the node's process needs Cyclone's prompt heartbeats (`topics.PROMPT_HEARTBEATS`): a node
    that waits for acknowledgements, under the clock drive. Only those: prompt heartbeats in every node
    cost the message drive a third more CPU (benchmarks/graph_bench.py), for waits it never makes."""
    return spec.waits_for_acks and values.get("graph.drive") == "clock"


def node_environment(spec: NodeSpec, values: Mapping[str, Any]) -> dict[str, str]:
    """What a process starting the node as an rclpy node adds to its environment: rmw_cyclonedds reads
    CYCLONEDDS_URI when the node is made, before the node can read its parameters."""
    if not prompt_heartbeats(spec, values):
        return {}
    return {"CYCLONEDDS_URI": with_prompt_heartbeats(os.environ.get("CYCLONEDDS_URI"))}


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
    keep_freed_heap()
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
        values["bag"] = find_bag(values["bag"], source)
    return values


ROS_OWN = frozenset({"use_sim_time", "start_type_description_service"})  # parameters rclpy declares itself
_RULE = re.compile(r"parameter override rule: '(?P<rule>[^']*)'")


def ros_arguments_error(text: str) -> str:
    """rcl's refusal of the ROS arguments, as one line a user can act on."""
    match = _RULE.search(text)
    if match is None:
        return "cannot parse the ROS arguments: " + text.split(", at ")[0]
    rule = match.group("rule")
    name, _, value = rule.removeprefix("-p ").partition(":=")
    hint = (f"; a ROS parameter cannot be a mapping: give each key as its own parameter, e.g. -p {name}.<key>:=<value>"
            if value.lstrip().startswith("{") else "")
    return f"parameter '{name}': cannot parse the override '{rule}'{hint}"


def _override_rules(args: list[str]) -> Iterator[str]:
    """The `[node:]name:=value` rules given with `-p` / `--param`, in order (the one scan of the
    arguments both readers below use)."""
    for flag, rule in itertools.pairwise(args):
        if flag in ("-p", "--param"):
            yield rule


def _refused_override(args: list[str] | None) -> str | None:
    """What rcl would refuse among the `-p name:=value` overrides (a value that is not YAML, or
    a mapping), said before rcl says it in two lines of its own."""
    for rule in _override_rules(list(args or [])):
        try:
            parsed = yaml.safe_load(rule.partition(":=")[2])
        except yaml.YAMLError:
            return ros_arguments_error(f"parameter override rule: '-p {rule}'")
        if isinstance(parsed, dict):
            return ros_arguments_error(f"parameter override rule: '-p {rule}'")
    return None


def _override_value(text: str) -> Any:
    """A `-p name:=value` value as rcl types it: YAML, but only true/false (any case) are booleans
    (PyYAML would also read yes/no/on/off as booleans, where rcl keeps the string)."""
    value = yaml.safe_load(text)
    if isinstance(value, bool) and text.strip().lower() not in ("true", "false"):
        return text
    return value


def command_line_overrides(args: list[str] | None, node_name: str) -> dict[str, Any]:
    """The `-p [node:]name:=value` rules of the ROS arguments that apply to `node_name`, the last
    one winning, as the values a user typed."""
    args = list(sys.argv if args is None else args)
    ros = args[args.index("--ros-args") + 1:] if "--ros-args" in args else []
    values: dict[str, Any] = {}
    for rule in _override_rules(ros):
        if ":=" not in rule:
            continue
        target, value = rule.split(":=", 1)
        node, _, name = target.rpartition(":")
        if node in ("", node_name, f"/{node_name}"):
            values[name] = _override_value(value)
    return values


def given_parameters(node: Any, args: list[str] | None) -> dict[str, Any]:
    """Every parameter given to an rclpy node (overrides and params files, dotted names), without
    the ones rclpy declares itself; the node must be created with
    `automatically_declare_parameters_from_overrides=True`, so none is silently left out.

    A `-p` on the command line wins over a params file wherever it stands, as a user expects: rcl
    lets a params file's entry for the node win over every `-p` once any `-p` stands before the file
    (`-p output:=X --params-file P -p seed:=3` ran with the file's seed), silently."""
    given = {name: p.value for name, p in node.get_parameters_by_prefix("").items() if name not in ROS_OWN}
    return {**given, **{name: value for name, value in command_line_overrides(args, node.get_name()).items()
                        if name not in ROS_OWN}}


def _interrupt(signum: int, frame: Any) -> None:
    """The first SIGINT or SIGTERM stops the body where it is; any later one is ignored, so that it
    cannot break into the clean stop (the checkpoint kept, the one line logged) the first began: a
    terminal's Ctrl-C under `ros2 launch` reaches the node twice, from the terminal and from launch."""
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, signal.SIG_IGN)
    raise KeyboardInterrupt


def stop_on_signal(node: Any) -> None:
    """SIGINT and SIGTERM end the node's spin at a callback's boundary: the signal only triggers a guard
    condition, whose callback (run by the executor) shuts rclpy down. rclpy's own handler chained to
    Python's, whose KeyboardInterrupt could land inside the executor's making of a Task, and the
    half-made Task printed a traceback at exit (in a launch's scenario player). Later signals are
    ignored: the first one's stop is under way."""
    import rclpy

    stop = node.create_guard_condition(rclpy.try_shutdown)

    def on_signal(signum: int, frame: Any) -> None:
        for each in (signal.SIGINT, signal.SIGTERM):
            signal.signal(each, signal.SIG_IGN)
        stop.trigger()

    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, on_signal)


def run_rclpy(name: str, args: list[str] | None, body: Callable[[Any], int], interruptible: bool = False) -> int:
    """The Jazzy main idiom for every node of this package: init, a node named `name` holding every
    parameter it was given, `body(node)` (which declares, validates, spins), shutdown. Each expected
    failure (ROS arguments rcl cannot parse, a bad parameter or bag: exit 2; the others of
    `exits.EXPECTED`) is one line and its exit code; Ctrl-C or a ROS shutdown ends a graph node quietly.

    `interruptible` (the orchestrator, whose body is a long computation, not a spin): rclpy's own
    signal handler only shuts the context down, which a search never looks at, so Ctrl-C was
    ignored until the search ended. Instead SIGINT and SIGTERM raise KeyboardInterrupt where the body
    is, the body turns it into its own `Interrupted` line, and an interruption anywhere else is exit
    code 130 too, never 0."""
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.impl.implementation_singleton import rclpy_implementation
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions

    refused = _refused_override(args if args is not None else sys.argv)
    if refused is not None:
        print(f"{name}: error: {refused}", file=sys.stderr)
        return EXIT_INPUT
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)  # ours: `_interrupt`, `stop_on_signal`
    except rclpy_implementation.RCLError as exc:
        print(f"{name}: error: {ros_arguments_error(str(exc))}", file=sys.stderr)
        return EXIT_INPUT
    # the handlers of before this call, back at its end (None: one not set from Python, the default)
    handlers = {signum: signal.getsignal(signum) or signal.SIG_DFL for signum in (signal.SIGINT, signal.SIGTERM)}
    if interruptible:
        for signum in handlers:
            signal.signal(signum, _interrupt)
    node = None
    try:
        node = Node(name, automatically_declare_parameters_from_overrides=True)
        return body(node)
    except EXPECTED_TYPES as exc:
        line, code = expected_failure(exc)
        if node is None:
            print(f"{name}: {line}", file=sys.stderr)
        else:
            node.get_logger().error(line)
        return code
    except (KeyboardInterrupt, ExternalShutdownException):
        return EXIT_INTERRUPTED if interruptible else 0
    except rclpy_implementation.RCLError:
        if rclpy.ok():
            raise
        return 0  # the context shut down (Ctrl-C, `ros2 launch` ending) while a spin was waiting: a normal stop
    finally:
        # the stop itself cannot be broken into: under `ros2 launch` a terminal's Ctrl-C reaches every node
        # twice (from the terminal and from launch), and the second came as a KeyboardInterrupt traceback
        # out of destroy_node in graph nodes too; the handlers of before this call come back after it
        for signum in handlers:
            signal.signal(signum, signal.SIG_IGN)
        try:
            if node is not None:
                node.destroy_node()
            rclpy.try_shutdown()
        finally:
            for signum, handler in handlers.items():
                signal.signal(signum, handler)


def _declare_defaults(node: Any, spec: NodeSpec, given: dict[str, Any]) -> None:
    """Declare the node's parameters it was not given, with their defaults and descriptions, so
    `ros2 param list/describe` show them."""
    from rcl_interfaces.msg import ParameterDescriptor

    for name in spec.params:
        param = SCHEMA[name]
        if name not in given and param.default is not None:
            node.declare_parameter(name, param.default, ParameterDescriptor(description=param.description))


def _run_rclpy(spec: NodeSpec, args: list[str] | None) -> int:
    def body(node: Any) -> int:
        from advperc_ros.ros.transport import RclpyTransport

        given = given_parameters(node, args)
        values, planner_params = node_values(given, spec.params, f"node '{spec.name}' parameters", spec.planner_params)
        _declare_defaults(node, spec, given)
        if prompt_heartbeats(spec, values) and PROMPT_HEARTBEATS not in os.environ.get("CYCLONEDDS_URI", ""):
            node.get_logger().warning(
                "graph.drive is clock, and this process's CYCLONEDDS_URI lacks prompt heartbeats: each frame may wait "
                "0.1-0.2 s for its readers' acknowledgements; start the node as the launch file does, with "
                f"CYCLONEDDS_URI={with_prompt_heartbeats(os.environ.get('CYCLONEDDS_URI'))}")
        transport = RclpyTransport(node)
        logic = spec.build(transport, _resolve(values, None), planner_params, node.get_logger())
        announce(transport, spec.name)
        poll = getattr(logic, "poll", None)
        if poll is not None:
            node.create_timer(POLL_PERIOD, poll)
        stop_on_signal(node)
        transport.executor.spin()  # rclpy.spin(node), at a fraction of its cost per message
        return 0

    return run_rclpy(spec.name, args, body)


def _flag(text: str) -> bool:
    if text not in ("true", "false"):
        raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")
    return text == "true"


def _run_cyclone(spec: NodeSpec, argv: list[str]) -> int:
    from advperc_ros.exceptions import DdsError
    from advperc_ros.ros.dds import DdsTransport

    parser = argparse.ArgumentParser(
        prog=spec.name, description=f"advperc_ros graph node '{spec.name}' over Cyclone DDS (no ROS needed).")
    given = parser.add_mutually_exclusive_group(required=True)
    given.add_argument("--params-file", help="orchestrator params YAML (as for `advperc attack`)")
    given.add_argument("--params-json", help="validated params as AttackParams.flat() gives them, with planner_params "
                       "(how the graph backend hands its children the params it checked)")
    parser.add_argument("--domain-id", type=int, help="DDS domain id (default: the file's dds.domain_id)")
    parser.add_argument("--localhost-only", type=_flag, help="true|false (default: the file's dds.localhost_only)")
    parser.add_argument("--partition", default="", help="DDS partition of every topic (the graph backend gives each "
                        "graph its own, so graphs on one domain cannot see each other; default: ROS 2's)")
    parser.add_argument("--exit-with-parent", action="store_true",
                        help="exit when the starting process dies (the graph backend sets it: no orphans)")
    options = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format=f"[{spec.name}] %(levelname)s: %(message)s")
    logger = logging.getLogger(spec.name)
    try:
        params = (load_params(options.params_file) if options.params_file is not None
                  else params_from_values(json.loads(options.params_json), None, "--params-json"))
        values = _resolve({name: params.get(name) for name in spec.params}, params.source)
        domain_id = params.dds.domain_id if options.domain_id is None else options.domain_id
        localhost_only = params.dds.localhost_only if options.localhost_only is None else options.localhost_only
        transport = DdsTransport(domain_id, localhost_only, options.partition, prompt_heartbeats(spec, values))
    except (*INPUT_ERRORS, DdsError) as exc:
        logger.error(str(exc))
        return EXIT_INPUT
    # SIGINT as SIGTERM: the loop ends between two spins, never inside a callback or a call into Cyclone
    stopping: list[int] = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda received, frame: stopping.append(received))
    parent = os.getppid()
    try:
        with transport:
            logic = spec.build(transport, values, dict(params.planner_params), logger)
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
    return 0
