"""Graph backend against embedded rollouts, side by side on the same error tensors.

    python benchmarks/graph_bench.py [--repeats 3] [--domain-id 120] [SCENARIO ...]

or from benchmarks/bench.py: `from graph_bench import bench_graph; bench_graph(repeats)`. Per
scenario (default idm_lane_following; an ObP scenario once its bag and params file exist): the
median time of a ground-truth rollout and of a lead-dropping one (agent slot 0 dropped from frame
20), embedded and through the five node processes over Cyclone DDS on loopback, their ratio, the
graph's start-up time (processes, discovery, warm-up rollout) and the largest difference between
the two backends' ego trajectories and signed distances.
"""

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from advperc_ros.attack import Stack  # noqa: E402
from advperc_ros.core.errors import PerceptionErrors  # noqa: E402
from advperc_ros.graph import GraphRollouts  # noqa: E402
from advperc_ros.params import load_params  # noqa: E402
from advperc_ros.ros.bag import read_scenario  # noqa: E402


def _median_time(run, errors: PerceptionErrors, repeats: int):
    times, result = [], None
    for _ in range(repeats):
        started = time.perf_counter()
        result = run(errors)
        times.append(time.perf_counter() - started)
    return statistics.median(times), result


def _difference(graph, embedded) -> float:
    if graph.ego.shape != embedded.ego.shape:
        return float("inf")
    finite = np.isfinite(embedded.distances)
    return float(max(np.abs(graph.ego - embedded.ego).max(), np.abs(graph.distances - embedded.distances)[finite].max()))


def bench_graph(repeats: int = 3, scenarios: tuple[str, ...] = ("idm_lane_following",), domain_id: int = 120) -> list[dict]:
    """Prints one line per scenario and error tensor; returns the same as dicts."""
    print(f"== Graph (5 node processes over Cyclone DDS, loopback) vs embedded rollouts, median of {repeats} ==")
    print(f"{'scenario':22s} {'errors':12s} {'frames':>6s} {'embedded s':>10s} {'graph s':>8s} {'ratio':>6s} {'max diff':>9s}")
    rows = []
    for name in scenarios:
        bag = REPO / "bags" / name
        scenario = read_scenario(bag)
        params = load_params(REPO / "config" / f"{name}.yaml").with_values(
            rollout_backend="graph", **{"dds.domain_id": domain_id, "dds.localhost_only": True})
        stack = Stack(scenario, params)
        none = PerceptionErrors.none(*scenario.agents.shape)
        cases = {"ground truth": none, "lead dropped": none.with_drop(0, 20, scenario.num_frames - 1)}
        started = time.perf_counter()
        with GraphRollouts(scenario, params, bag) as graph:
            startup = time.perf_counter() - started
            for label, errors in cases.items():
                embedded_s, embedded = _median_time(stack.rollout, errors, repeats)
                graph_s, result = _median_time(graph.rollout, errors, repeats)
                row = {"scenario": name, "errors": label, "frames": result.num_frames, "embedded_s": embedded_s,
                       "graph_s": graph_s, "ratio": graph_s / embedded_s, "max_difference": _difference(result, embedded),
                       "startup_s": startup}
                rows.append(row)
                print(f"{name:22s} {label:12s} {row['frames']:6d} {embedded_s:10.3f} {graph_s:8.3f} {row['ratio']:6.1f} "
                      f"{row['max_difference']:9.1e}")
        print(f"{name:22s} graph start-up (processes, discovery, warm-up rollout): {startup:.1f} s")
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenarios", nargs="*", default=["idm_lane_following"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--domain-id", type=int, default=120)
    options = parser.parse_args()
    bench_graph(options.repeats, tuple(options.scenarios), options.domain_id)
