"""The node graph against embedded rollouts, side by side on the same error tensors.

    python benchmarks/graph_bench.py [--repeats 5] [--hops 500] [--domain-id 120] [SCENARIO ...]

or from benchmarks/bench.py: `from graph_bench import bench_graph; bench_graph(repeats)`. Per
scenario (default idm_lane_following and obp_overtake): a ground-truth rollout and a lead-dropping
one (agent slot 0 dropped from frame 20), each run `repeats` times on three backends in turn, so
that a change in the machine's load hits all alike: embedded; the five node processes over bare
Cyclone DDS (what `--backend graph` starts); and, when ROS 2 is sourced, the five nodes as rclpy
nodes driven from an rclpy node (what `ros2 launch advperc_ros attack.launch.py` runs). Printed:
the median times, their ratios to embedded, each graph's start-up time (processes, discovery,
warm-up rollout) and the largest difference from the embedded ego trajectories and signed
distances; then one ratio per scenario and backend against the issue's goal for its planner: each
graph rollout over the embedded rollout of the same tensor run just before it, the median of those
pairs per tensor, weighted by the tensors' embedded times. Pairs, because this shared machine's
speed drifts by a quarter within seconds (the same embedded rollout took 3.2-5.2 s in one run): a
ratio of totals moves with every slow spell that falls on one side, a pair sees the same machine on
both. The embedded rollouts' own spread (slowest over fastest) is printed as the run's noise. Beside
the ratio, two floors measured in the same run:
the hops' (hop_cost.py's round trip over the backend's transport, `--hops` ping-pongs, for the 2
hops a frame waits for in sequence, added to the embedded frame) and the CPU's (all the graph's
processes' CPU time spread perfectly over the machine's cores); and each node's CPU time against the
embedded rollout's, with the sum of the two a frame passes one after another (player, planner: the
injector and the tracker work a frame ahead, beside the planner), which no number of cores brings
under: the sequence's floor. All DDS traffic stays on loopback
(the rclpy graph relies on ../shared/ros2/activate.sh's CYCLONEDDS_URI). The load average is
printed too: on a shared machine the ratios move with it.
"""

import argparse
import contextlib
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

import hop_cost  # noqa: E402

from advperc_ros.backends.embedded import Stack  # noqa: E402
from advperc_ros.backends.graph.rollouts import GraphRollouts  # noqa: E402
from advperc_ros.configs import core_configs  # noqa: E402
from advperc_ros.core.perception_errors import PerceptionErrors  # noqa: E402
from advperc_ros.core.rollout import RolloutResult  # noqa: E402
from advperc_ros.core.scenario import Scenario  # noqa: E402
from advperc_ros.heap import keep_freed_heap  # noqa: E402
from advperc_ros.nodes.graph_nodes import SPECS, ros_parameters  # noqa: E402
from advperc_ros.params import AttackParams, load_params  # noqa: E402
from advperc_ros.ros.bag import read_scenario  # noqa: E402

SCENARIOS = ("idm_lane_following", "obp_overtake")
GOALS = {("cyclone", "idm"): 1.5, ("rclpy", "idm"): 3.0, ("cyclone", "obp"): 1.1, ("rclpy", "obp"): 1.1}
"""graph / embedded rollout time, per backend and planner (issue 10)"""


def _cpu_seconds(pids: list[int]) -> float:
    """CPU time (user + system) the processes `pids` have used so far (Linux /proc)."""
    total = 0
    for pid in pids:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        total += int(fields[11]) + int(fields[12])  # utime, stime (fields 14 and 15 of stat)
    return total / os.sysconf("SC_CLK_TCK")


# the nodes a frame passes one after another: their CPU time cannot overlap within a frame, so over any number
# of cores a rollout takes at least its sum. With the ground truth a frame ahead (our nodes, driven by messages)
# the injector and the tracker work on the next frame beside the planner, as the rule monitor does
IN_SEQUENCE = ("scenario_player", "planner")


def node_pids(graph: GraphRollouts) -> dict[str, int]:
    """The graph's node processes by node name (ours, or the rclpy ones `rclpy_graph` started)."""
    return {name: process.pid for name, process in graph.processes.running.items()} or graph.node_pids


@contextlib.contextmanager
def rclpy_graph(scenario, params, bag: Path, domain_id: int) -> Iterator[GraphRollouts]:
    """The launch file's graph without launch: the five nodes as rclpy processes (parameters as the
    launch file gives them) on `domain_id`, driven through an rclpy node of this process."""
    import rclpy
    from rclpy.node import Node

    from advperc_ros.ros.transport import RclpyTransport

    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id))
    with tempfile.TemporaryDirectory(prefix="advperc-bench-") as folder:
        node_params = Path(folder) / "nodes.yaml"
        node_params.write_text(yaml.safe_dump({spec.name: {"ros__parameters": ros_parameters(spec, params, bag)}
                                               for spec in SPECS}))
        nodes = [subprocess.Popen([sys.executable, "-m", f"advperc_ros.nodes.{spec.name}", "--ros-args",
                                   "--params-file", str(node_params)], env=env, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL) for spec in SPECS]
        rclpy.init(domain_id=domain_id)
        try:
            node = Node("graph_bench")
            with GraphRollouts(scenario, core_configs(params.with_values(**{"graph.spawn_nodes": False})), bag,
                               RclpyTransport(node)) as graph:
                graph.node_pids = {spec.name: process.pid for spec, process in zip(SPECS, nodes)}  # to measure
                yield graph
        finally:
            rclpy.try_shutdown()
            for process in nodes:
                process.terminate()
            for process in nodes:
                process.wait(timeout=30)


def _timed(run, errors: PerceptionErrors) -> tuple[float, RolloutResult]:
    started = time.perf_counter()
    result = run(errors)
    return time.perf_counter() - started, result


def _difference(graph: RolloutResult, embedded: RolloutResult) -> float:
    if graph.ego.shape != embedded.ego.shape:
        return float("inf")
    finite = np.isfinite(embedded.distances)
    return float(max(np.abs(graph.ego - embedded.ego).max(), np.abs(graph.distances - embedded.distances)[finite].max()))


def bundled_on_graph(name: str, domain_id: int) -> tuple[Path, Scenario, AttackParams, Stack]:
    """A bundled scenario's bag, scenario, params set for the graph backend on loopback with `domain_id`,
    and its embedded stack: what each side-by-side comparison starts from."""
    bag = REPO / "bags" / name
    scenario = read_scenario(bag)
    params = load_params(REPO / "config" / f"{name}.yaml").with_values(
        rollout_backend="graph", **{"dds.domain_id": domain_id, "dds.localhost_only": True})
    return bag, scenario, params, Stack(scenario, core_configs(params))


def bench_graph(repeats: int = 5, scenarios: tuple[str, ...] = SCENARIOS, domain_id: int = 120,
                hops: int = 500) -> list[dict]:
    """Prints one line per scenario and error tensor, then one ratio per scenario and backend with
    its floors (no hop floor with `hops` 0); returns the per-tensor rows as dicts."""
    keep_freed_heap()  # the embedded rollouts run with the heap `advperc attack` and the nodes have
    backends = tuple(kind for kind in hop_cost.available() if kind in ("cyclone", "rclpy"))  # our nodes' transports
    if len(backends) == 1:
        print("(ROS 2 not sourced: the rclpy graph is left out; source ../shared/ros2/activate.sh to include it)")
    round_trip = {}
    if hops:
        print(f"== One hop (hop_cost.py, {hops} ping-pongs); {hop_cost.load_average()} ==")
        for offset, backend in enumerate(backends):
            cpu, round_trip[backend] = hop_cost.measure(backend, domain_id + 2 + offset, hops)
            print(f"{backend:8s} relay CPU {cpu * 1e6:6.1f} us/message, round trip {round_trip[backend] * 1e6:6.1f} us")
    print(f"== Graphs (5 node processes, loopback) vs embedded rollouts, median of {repeats}, in turn; "
          f"{hop_cost.load_average()} ==")
    print(f"{'scenario':22s} {'errors':12s} {'frames':>6s} {'embedded s':>10s} {'spread':>6s} "
          + " ".join(f"{b + ' s':>9s} {'ratio':>6s} {'diff':>8s}" for b in backends))
    rows = []
    for name in scenarios:
        bag, scenario, params, stack = bundled_on_graph(name, domain_id)
        none = PerceptionErrors.none(*scenario.agents.shape)
        cases = {"ground truth": none, "lead dropped": none.with_drop(0, 20, scenario.num_frames - 1)}
        with contextlib.ExitStack() as stacked:
            graphs, startup = {}, {}
            for backend in backends:
                started = time.perf_counter()
                graphs[backend] = stacked.enter_context(
                    GraphRollouts(scenario, core_configs(params), bag) if backend == "cyclone"
                    else rclpy_graph(scenario, params, bag, domain_id + 1))
                startup[backend] = time.perf_counter() - started
            for label, errors in cases.items():
                cpu = {"embedded": 0.0, **dict.fromkeys(backends, 0.0)}  # CPU s of the rollouts, all processes
                per_node = {backend: dict.fromkeys((spec.name for spec in SPECS), 0.0) for backend in backends}
                times: dict[str, list[float]] = {"embedded": [], **{b: [] for b in backends}}
                pairs: dict[str, list[float]] = {b: [] for b in backends}  # each over the embedded run just before
                results = {}
                for _ in range(repeats):
                    before = time.process_time()
                    seconds, embedded = _timed(stack.rollout, errors)
                    cpu["embedded"] += time.process_time() - before
                    times["embedded"].append(seconds)
                    for backend, graph in graphs.items():
                        pids = node_pids(graph)
                        nodes_before = {node: _cpu_seconds([pid]) for node, pid in pids.items()}
                        before = time.process_time()
                        seconds, results[backend] = _timed(graph.rollout, errors)
                        nodes_used = {node: _cpu_seconds([pid]) - nodes_before[node] for node, pid in pids.items()}
                        cpu[backend] += sum(nodes_used.values()) + time.process_time() - before
                        for node, used in nodes_used.items():
                            per_node[backend][node] += used
                        times[backend].append(seconds)
                        pairs[backend].append(seconds / times["embedded"][-1])
                median = {key: statistics.median(values) for key, values in times.items()}
                for backend in backends:
                    rows.append({"scenario": name, "planner": params.planner, "backend": backend, "errors": label,
                                 "cpu_s": cpu[backend], "embedded_cpu_s": cpu["embedded"],
                                 "node_cpu_s": per_node[backend],
                                 "frames": results[backend].num_frames, "embedded_s": median["embedded"],
                                 "graph_s": median[backend], "ratio": statistics.median(pairs[backend]),
                                 "embedded_spread": max(times["embedded"]) / min(times["embedded"]),
                                 "max_difference": _difference(results[backend], embedded),
                                 "startup_s": startup[backend]})
                mine = rows[-len(backends):]
                print(f"{name:22s} {label:12s} {mine[0]['frames']:6d} {median['embedded']:10.3f} "
                      f"{mine[0]['embedded_spread']:6.2f} "
                      + " ".join(f"{r['graph_s']:9.3f} {r['ratio']:6.2f} {r['max_difference']:8.1e}" for r in mine))
        print(f"{name:22s} start-up (processes, discovery, warm-up rollout): "
              + ", ".join(f"{b} {s:.1f} s" for b, s in startup.items()))
    print(f"-- graph / embedded per scenario and backend (paired, weighted by embedded time); {hop_cost.load_average()}")
    for name in scenarios:
        for backend in backends:
            mine = [row for row in rows if row["scenario"] == name and row["backend"] == backend]
            ratio = sum(row["ratio"] * row["embedded_s"] for row in mine) / sum(row["embedded_s"] for row in mine)
            spread = max(row["embedded_spread"] for row in mine)
            goal = GOALS.get((backend, mine[0]["planner"]))
            verdict = f" (goal <= {goal:g}x: {'met' if ratio <= goal else 'NOT met'})" if goal else ""
            # the hops' floor: the embedded frame plus the hops a frame waits for in sequence
            frame = statistics.fmean(row["embedded_s"] / row["frames"] for row in mine)
            hop_floor = (f"; hops' floor {1 + hop_cost.HOPS_IN_SEQUENCE * round_trip[backend] / 2 / frame:.2f}x"
                         if backend in round_trip else "")
            # the CPU's floor: the graph's CPU work spread perfectly over this machine's cores, against the
            # embedded rollout's CPU time (CPU, not wall time: other load on the machine cancels out)
            embedded_cpu = sum(row["embedded_cpu_s"] for row in mine)
            work = sum(row["cpu_s"] for row in mine) / embedded_cpu
            nodes = {node: sum(row["node_cpu_s"][node] for row in mine) / embedded_cpu for node in mine[0]["node_cpu_s"]}
            sequence = sum(nodes[node] for node in IN_SEQUENCE)
            print(f"{name:22s} {backend:8s} {ratio:5.2f}x{verdict} (the embedded rollouts' own spread {spread:.2f}x)"
                  f"{hop_floor}; CPU {work:.2f}x the embedded rollout's, "
                  f"over {os.cpu_count()} cores a floor of {work / (os.cpu_count() or 1):.2f}x; the nodes in sequence "
                  f"{sequence:.2f}x (" + ", ".join(f"{node} {share:.2f}" for node, share in nodes.items()) + ")")
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenarios", nargs="*", default=list(SCENARIOS))
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--hops", type=int, default=500, help="ping-pongs per transport for the hops' floor (0: none)")
    parser.add_argument("--domain-id", type=int, default=120, help="the first of four domain ids it uses")
    options = parser.parse_args()
    bench_graph(options.repeats, tuple(options.scenarios), options.domain_id, options.hops)
