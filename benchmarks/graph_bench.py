"""Graph backend against embedded rollouts, side by side on the same error tensors.

    python benchmarks/graph_bench.py [--repeats 5] [--domain-id 120] [SCENARIO ...]

or from benchmarks/bench.py: `from graph_bench import bench_graph; bench_graph(repeats)`. Per
scenario (default idm_lane_following and obp_overtake): a ground-truth rollout and a lead-dropping
one (agent slot 0 dropped from frame 20), each run `repeats` times embedded and through the five
node processes over Cyclone DDS on loopback, alternately, so that a change in the machine's load
hits both backends alike; the median times, their ratio, the graph's start-up time (processes,
discovery, warm-up rollout) and the largest difference between the two backends' ego
trajectories and signed distances. Then one ratio per scenario (total graph time over total
embedded time of its rollouts) against the issue's target for its planner. The load average is
printed too: on a shared machine the ratios move with it.
"""

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from advperc_ros.attack import Stack  # noqa: E402
from advperc_ros.core.errors import PerceptionErrors  # noqa: E402
from advperc_ros.core.rollout import RolloutResult  # noqa: E402
from advperc_ros.graph import GraphRollouts  # noqa: E402
from advperc_ros.params import load_params  # noqa: E402
from advperc_ros.ros.bag import read_scenario  # noqa: E402

SCENARIOS = ("idm_lane_following", "obp_overtake")
TARGETS = {"idm": 3.0, "obp": 1.3}  # graph / embedded rollout time, per planner (issue 4)


def _timed(run, errors: PerceptionErrors) -> tuple[float, RolloutResult]:
    started = time.perf_counter()
    result = run(errors)
    return time.perf_counter() - started, result


def _difference(graph: RolloutResult, embedded: RolloutResult) -> float:
    if graph.ego.shape != embedded.ego.shape:
        return float("inf")
    finite = np.isfinite(embedded.distances)
    return float(max(np.abs(graph.ego - embedded.ego).max(), np.abs(graph.distances - embedded.distances)[finite].max()))


def _load() -> str:
    return "load average " + " ".join(f"{x:.2f}" for x in os.getloadavg())


def bench_graph(repeats: int = 5, scenarios: tuple[str, ...] = SCENARIOS, domain_id: int = 120) -> list[dict]:
    """Prints one line per scenario and error tensor, then one ratio per scenario; returns the
    per-tensor rows as dicts."""
    print(f"== Graph (5 node processes over Cyclone DDS, loopback) vs embedded rollouts, median of {repeats}, "
          f"alternating; {_load()} ==")
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
                times: dict[str, list[float]] = {"embedded": [], "graph": []}
                for _ in range(repeats):
                    embedded_s, embedded = _timed(stack.rollout, errors)
                    graph_s, result = _timed(graph.rollout, errors)
                    times["embedded"].append(embedded_s)
                    times["graph"].append(graph_s)
                embedded_s, graph_s = statistics.median(times["embedded"]), statistics.median(times["graph"])
                row = {"scenario": name, "planner": params["planner"], "errors": label, "frames": result.num_frames,
                       "embedded_s": embedded_s, "graph_s": graph_s, "ratio": graph_s / embedded_s,
                       "max_difference": _difference(result, embedded), "startup_s": startup}
                rows.append(row)
                print(f"{name:22s} {label:12s} {row['frames']:6d} {embedded_s:10.3f} {graph_s:8.3f} {row['ratio']:6.2f} "
                      f"{row['max_difference']:9.1e}")
        print(f"{name:22s} graph start-up (processes, discovery, warm-up rollout): {startup:.1f} s")
    print(f"-- graph / embedded per scenario (all its rollouts); {_load()}")
    for name in scenarios:
        mine = [row for row in rows if row["scenario"] == name]
        ratio = sum(row["graph_s"] for row in mine) / sum(row["embedded_s"] for row in mine)
        target = TARGETS.get(mine[0]["planner"])
        verdict = f" (target <= {target:g}x: {'met' if ratio <= target else 'NOT met'})" if target else ""
        print(f"{name:22s} {ratio:5.2f}x{verdict}")
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenarios", nargs="*", default=list(SCENARIOS))
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--domain-id", type=int, default=120)
    options = parser.parse_args()
    bench_graph(options.repeats, tuple(options.scenarios), options.domain_id)
