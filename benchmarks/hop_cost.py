"""What one message hop costs a graph node, by transport: the floor under the graph's ratios.

    python benchmarks/hop_cost.py [--messages 2000] [--domain-id 124]

A relay process receives a message and publishes it back, `--messages` times in ping-pong with
this process, doing no work of its own: over bare Cyclone DDS (`DdsTransport.spin_once`, as the
graph backend's nodes run) and, when ROS 2 is sourced, as an rclpy node spun by one executor that
holds it (as `rclpy.spin(node)` spins the nodes under `ros2 run` and the launch file). Printed per transport: the relay's CPU time per
message received and sent (executor or waitset wake-up, take, callback, publish) and the round
trip's wall time. A graph frame is 10 such receptions across its six processes (player 2,
injector 1, tracker 1, planner 2, rule monitor 2, orchestrator 2; 12 on a recorded rollout), 4 of
them in sequence (player -> injector -> tracker -> planner -> player): 10 x the CPU per message is
what the transport alone costs a frame in CPU, 4 x half the round trip what it adds to the frame's
wall time, against the embedded rollout's whole frame (about 0.8 ms on idm_lane_following). All
traffic stays on loopback.
"""

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from advperc_ros.ros.topics import CONTROL_TYPE  # noqa: E402

PING, PONG = "/advperc_bench/ping", "/advperc_bench/pong"
RECEPTIONS_PER_FRAME = 10
HOPS_IN_SEQUENCE = 4


def relay(transport_kind: str, domain_id: int, count: int) -> None:
    """The child: echo `count` pings, then print the CPU seconds that took."""
    if transport_kind == "rclpy":
        import rclpy
        from rclpy.node import Node

        from advperc_ros.ros.transport import RclpyTransport

        rclpy.init(domain_id=domain_id)
        node = Node("hop_relay")
        transport = RclpyTransport(node)
    else:
        from advperc_ros.ros.dds import DdsTransport

        transport = DdsTransport(domain_id, localhost_only=True)
    pong = transport.publisher(PONG, CONTROL_TYPE)
    seen: list[float] = []

    def echo(data: bytes) -> None:
        if not seen:
            seen.append(time.process_time())
        pong.publish(data)
        seen.append(0.0)

    transport.subscriber(PING, CONTROL_TYPE, callback=echo, raw=True)
    while len(seen) <= count:
        transport.spin_once(0.05)  # rclpy: one executor holding the node, as rclpy.spin(node) keeps it
    print(time.process_time() - seen[0], flush=True)


def measure(transport_kind: str, domain_id: int, count: int) -> tuple[float, float]:
    """(relay CPU s per message, round-trip wall s) over `count` ping-pongs after a warm-up."""
    from advperc_ros.ros import messages as msgs

    child = subprocess.Popen([sys.executable, __file__, "--relay", transport_kind, "--domain-id", str(domain_id),
                              "--messages", str(count + 1)], stdout=subprocess.PIPE, text=True)
    if transport_kind == "rclpy":
        import rclpy
        from rclpy.node import Node

        from advperc_ros.ros.transport import RclpyTransport

        rclpy.init(domain_id=domain_id)
        transport = RclpyTransport(Node("hop_driver"))
    else:
        from advperc_ros.ros.dds import DdsTransport

        transport = DdsTransport(domain_id, localhost_only=True)
    got: list[bytes] = []
    transport.subscriber(PONG, CONTROL_TYPE, callback=got.append, raw=True)
    ping = transport.publisher(PING, CONTROL_TYPE)
    payload = bytes(msgs.TYPESTORE.serialize_cdr(msgs.TYPESTORE.types[CONTROL_TYPE](data="x" * 64), CONTROL_TYPE))
    deadline = time.monotonic() + 30
    while not got:  # warm-up: discovery, until the relay answers
        if time.monotonic() > deadline:
            child.kill()
            raise RuntimeError(f"{transport_kind}: the relay never answered")
        ping.publish(payload)
        transport.spin_once(0.1)
    started = time.perf_counter()
    for _ in range(count):
        before = len(got)
        ping.publish(payload)
        while len(got) == before:
            transport.spin_once(1.0)
    wall = (time.perf_counter() - started) / count
    cpu = float(child.communicate(timeout=60)[0].split()[-1])
    if transport_kind == "rclpy":
        import rclpy

        rclpy.try_shutdown()
    return cpu / count, wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=2000)
    parser.add_argument("--domain-id", type=int, default=124)
    parser.add_argument("--relay", choices=("cyclone", "rclpy"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.relay:
        relay(args.relay, args.domain_id, args.messages)
        return
    kinds = ["cyclone"]
    try:
        import rclpy  # noqa: F401
        kinds.append("rclpy")
    except ImportError:
        print("(ROS 2 not sourced: rclpy left out)")
    print(f"== one hop: relay CPU per message and round trip, {args.messages} ping-pongs; load average "
          + " ".join(f"{x:.2f}" for x in os.getloadavg()))
    for offset, kind in enumerate(kinds):
        cpu, wall = measure(kind, args.domain_id + offset, args.messages)
        print(f"{kind:8s} relay CPU {cpu * 1e6:6.1f} us/message, round trip {wall * 1e6:6.1f} us; per graph frame: "
              f"{cpu * RECEPTIONS_PER_FRAME * 1e3:.2f} ms CPU ({RECEPTIONS_PER_FRAME} receptions), "
              f"{wall / 2 * HOPS_IN_SEQUENCE * 1e3:.2f} ms wall ({HOPS_IN_SEQUENCE} hops in sequence)")


if __name__ == "__main__":
    main()
