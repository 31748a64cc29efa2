"""What one message hop costs a graph node, by transport: the floor under the graph's ratios.

    python benchmarks/hop_cost.py [--messages 2000] [--domain-id 124]

or from graph_bench.py, which runs it beside the graphs (`measure`). A relay process receives a
message and publishes it back, `--messages` times in ping-pong with this process (one message in
flight), doing no work of its own, over each transport:

- `cyclone`: bare Cyclone DDS (`DdsTransport.spin_once`), as the graph backend's nodes run;
- `rclpy` (ROS 2 sourced): an rclpy node spun by `NodeExecutor`, as our nodes run under `ros2 run`
  and the launch file;
- `rclpy-executor` (ROS 2 sourced): the same node spun by rclpy's SingleThreadedExecutor, as
  `rclpy.spin(node)` runs a team's node (and ran ours before NodeExecutor).

Printed per transport: the relay's CPU time per message received and sent (wake-up, take,
callback, publish) and the round trip's wall time. A graph frame is 8 such receptions across the
five nodes (player 2, injector 1, tracker 1, planner 2, rule monitor 2; the orchestrator takes
its 2 per-frame messages without waking for them), 2 of them in sequence (player -> planner ->
player: with the ground truth a frame ahead, the injector and the tracker work on the next frame
beside the planner): 8 x the CPU per message is about what the transport costs a frame in CPU,
2 x half the round trip what it adds to the frame's wall time, against the embedded rollout's
whole frame (about 0.8 ms on idm_lane_following). All traffic stays on loopback.
"""

import argparse
import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from advperc_ros.ros.topics import CONTROL_TYPE  # noqa: E402

PING, PONG = "/advperc_bench/ping", "/advperc_bench/pong"
KINDS = ("cyclone", "rclpy", "rclpy-executor")
RECEPTIONS_PER_FRAME = 8
# the hops a frame waits for one after another: the odometry to the planner and the plan back to the player
# (with the ground truth a frame ahead, the injector's and the tracker's hops run beside the planner)
HOPS_IN_SEQUENCE = 2
# what a ping says, in its std_msgs/String: the warm-up's may be answered late or twice, so they are
# neither timed nor counted; the stop ends the relay
WARM_UP, MEASURED, STOP = "warm-up", "x" * 64, "stop"


def _endpoint(kind: str, domain_id: int, name: str) -> tuple[Any, Callable[[float], object]]:
    """(a transport, its spin(timeout)) for one end of the ping-pong, over `kind`."""
    if kind == "cyclone":
        from advperc_ros.ros.dds import DdsTransport

        transport = DdsTransport(domain_id, localhost_only=True)
        return transport, transport.spin_once
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from advperc_ros.ros.transport import RclpyTransport

    rclpy.init(domain_id=domain_id)
    node = Node(name)
    transport = RclpyTransport(node)
    if kind == "rclpy":
        return transport, transport.spin_once
    executor = SingleThreadedExecutor()  # one executor holding the node for good, as rclpy.spin(node) keeps it
    executor.add_node(node)
    return transport, lambda timeout: executor.spin_once(timeout_sec=timeout)


def _string(text: str) -> bytes:
    from advperc_ros.ros import messages as msgs

    return bytes(msgs.TYPESTORE.serialize_cdr(msgs.string(text), CONTROL_TYPE))


def relay(kind: str, domain_id: int) -> None:
    """The child: echo every ping until the stop, then print the CPU seconds from the first
    measured ping to the stop and the number of measured pings."""
    transport, spin = _endpoint(kind, domain_id, "hop_relay")
    pong = transport.publisher(PONG, CONTROL_TYPE)
    measured, stopped = MEASURED.encode(), STOP.encode()
    cpu: list[float] = []  # at the first measured ping, then at the stop
    pings = [0]

    def echo(data: bytes) -> None:
        if stopped in data:
            cpu.append(time.process_time())
            return
        if measured in data:
            if not cpu:
                cpu.append(time.process_time())
            pings[0] += 1
        pong.publish(data)

    transport.subscriber(PING, CONTROL_TYPE, callback=echo, raw=True)
    while len(cpu) < 2:
        spin(0.05)
    print(cpu[1] - cpu[0], pings[0], flush=True)


def measure(kind: str, domain_id: int, count: int) -> tuple[float, float]:
    """(relay CPU s per message, round-trip wall s) over `count` ping-pongs after a warm-up."""
    child = subprocess.Popen([sys.executable, __file__, "--relay", kind, "--domain-id", str(domain_id)],
                             stdout=subprocess.PIPE, text=True)
    transport, spin = _endpoint(kind, domain_id, "hop_driver")
    got: list[bytes] = []
    transport.subscriber(PONG, CONTROL_TYPE, callback=got.append, raw=True)
    ping = transport.publisher(PING, CONTROL_TYPE)
    warm_up, measured, stop = _string(WARM_UP), _string(MEASURED), _string(STOP)
    deadline = time.monotonic() + 30
    while not got:  # warm-up: discovery, until the relay answers
        if time.monotonic() > deadline:
            child.kill()
            raise RuntimeError(f"{kind}: the relay never answered")
        ping.publish(warm_up)
        spin(0.1)
    answered = -1
    while answered != len(got):  # the warm-up's other answers, until none comes for 0.2 s
        answered = len(got)
        spin(0.2)
    started = time.perf_counter()
    for _ in range(count):
        before = len(got)
        ping.publish(measured)
        while len(got) == before:
            spin(1.0)
    wall = (time.perf_counter() - started) / count
    ping.publish(stop)
    cpu, relayed = child.communicate(timeout=60)[0].split()[-2:]
    if int(relayed) != count:
        raise RuntimeError(f"{kind}: the relay counted {relayed} pings, not {count}")
    if kind != "cyclone":
        import rclpy

        rclpy.try_shutdown()
    return float(cpu) / count, wall


def available() -> tuple[str, ...]:
    """The kinds this environment can run: all of them with ROS 2 sourced, else bare Cyclone alone."""
    try:
        import rclpy  # noqa: F401
    except ImportError:
        return KINDS[:1]
    return KINDS


def load_average() -> str:
    """"load average" and its three figures: every benchmark prints it, since on a shared machine the
    ratios move with it."""
    return "load average " + " ".join(f"{x:.2f}" for x in os.getloadavg())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=2000)
    parser.add_argument("--domain-id", type=int, default=124)
    parser.add_argument("--relay", choices=KINDS, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.relay:
        relay(args.relay, args.domain_id)
        return
    kinds = available()
    if len(kinds) == 1:
        print("(ROS 2 not sourced: rclpy left out)")
    print(f"== one hop: relay CPU per message and round trip, {args.messages} ping-pongs; {load_average()}")
    for offset, kind in enumerate(kinds):
        cpu, wall = measure(kind, args.domain_id + offset, args.messages)
        print(f"{kind:14s} relay CPU {cpu * 1e6:6.1f} us/message, round trip {wall * 1e6:6.1f} us; per graph frame: "
              f"{cpu * RECEPTIONS_PER_FRAME * 1e3:.2f} ms CPU ({RECEPTIONS_PER_FRAME} receptions), "
              f"{wall / 2 * HOPS_IN_SEQUENCE * 1e3:.2f} ms wall ({HOPS_IN_SEQUENCE} hops in sequence)")


if __name__ == "__main__":
    main()
