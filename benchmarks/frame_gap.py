"""Where a graph frame's time goes beyond the planner's: the wall-clock gap between two plan() calls, split.

    python benchmarks/frame_gap.py [--rollouts 3] [--domain-id 184] [SCENARIO]

On obp_overtake a frame is some 25 ms of planning and the graph's goal is 1.1x the embedded rollout,
so what the graph adds between two plans decides it. The ground-truth rollout of SCENARIO
(obp_overtake by default) runs `--rollouts` times embedded and over each graph backend (the bare
Cyclone nodes; with ROS 2 sourced, the rclpy nodes too), in turn. `_plan_timer/sitecustomize.py`
stamps, on one clock for every process (CLOCK_MONOTONIC), each plan() call in this process and in
the planner node, the player's `on_plan` and the planner node's `on_odometry` as they are entered,
and each publish. A frame's gap, from plan() returning to the next plan() starting, then splits:

1. the planner node: plan() returned -> the plan's publish starts (encoding the Path);
2. the plan's publish -> the player's on_plan (the write, the hop, the player's process waking);
3. the player: on_plan -> the odometry's publish starts (decoding the plan, moving the ego along it,
   encoding the odometry; the rule value is in long before);
4. the odometry's publish -> the planner node's on_odometry (the write to the planner, the rule
   monitor and the orchestrator, the hop, the planner's process waking);
5. the planner node: on_odometry -> plan() starts (decoding the odometry, pairing it with the
   tracks, which came during the previous plan: perception runs a frame ahead).

Printed per backend: each step's median and mean (a gap's tail is mostly a process waiting for a
core), their sum against the embedded rollout's gap between two plan() calls (tracking, injection,
rule, moving the ego), plan()'s wall time in both, and the median rollout time over the embedded
one's (paired, as graph_bench.py pairs them). All DDS traffic stays on loopback. No timings are
asserted anywhere: the machine is shared.
"""

import argparse
import bisect
import itertools
import os
import statistics
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path

from graph_bench import bundled_on_graph, node_pids, rclpy_graph
from hop_cost import available, load_average
from planner_process_cost import TIMER, node_report, plan_timer

from advperc_ros.backends.graph.rollouts import GraphRollouts
from advperc_ros.configs import core_configs
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.heap import keep_freed_heap
from advperc_ros.ros.interfaces.registry import load_profile

STEPS = ("1 plan() returned -> plan published", "2 plan published -> player's on_plan",
         "3 player's on_plan -> odometry published", "4 odometry published -> planner's on_odometry",
         "5 planner's on_odometry -> plan() starts")


def _after(times: list[float], moment: float | None) -> float | None:
    """The first of the sorted `times` after `moment`, or None."""
    if moment is None:
        return None
    at = bisect.bisect(times, moment)
    return times[at] if at < len(times) else None


def _starts(report: dict, what: str) -> list[float]:
    return sorted(start for name, start, _ in report["marks"] if name == what)


def graph_gaps(planner: dict, player: dict, plan_topic: str, ego_topic: str) -> dict[str, list[float]]:
    """Per frame of one graph rollout, the seconds of each of `STEPS`, from the two nodes' reports."""
    published = _starts(planner, f"publish {plan_topic}")
    odometry_in = _starts(planner, "on_odometry")
    plan_in = _starts(player, "on_plan")
    odometry_out = _starts(player, f"publish {ego_topic}")
    starts = sorted(start for start, _ in planner["plans"])
    steps: dict[str, list[float]] = {step: [] for step in (*STEPS, "gap")}
    for _, end in planner["plans"]:
        moments = [end]
        for times in (published, plan_in, odometry_out, odometry_in, starts):
            moments.append(_after(times, moments[-1]))
        if moments[-1] is None:  # the rollout's last plan
            continue
        for step, earlier, later in zip(STEPS, moments, moments[1:]):
            steps[step].append(later - earlier)
        steps["gap"].append(moments[-1] - end)
    return steps


def embedded_gaps(calls: list[tuple[float, float]]) -> list[float]:
    return [later[0] - earlier[1] for earlier, later in itertools.pairwise(calls)]


def frame_gap(name: str, rollouts: int, domain_id: int) -> None:
    bag, scenario, params, stack = bundled_on_graph(name, domain_id)
    profile = load_profile(params.graph.interface)
    errors = PerceptionErrors.none(*scenario.agents.shape)
    stack.rollout(errors)  # warm
    backends = [kind for kind in available() if kind in ("cyclone", "rclpy")]
    with tempfile.TemporaryDirectory(prefix="advperc-frame-gap-") as folder, ExitStack() as stacked:
        os.environ["ADVPERC_PLAN_TIMER"] = folder  # the node processes inherit it, and the wrapper's path
        os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(TIMER), os.environ.get("PYTHONPATH")) if p)
        graphs = {backend: stacked.enter_context(GraphRollouts(scenario, core_configs(params), bag) if backend == "cyclone" else
                                                 rclpy_graph(scenario, params, bag, domain_id + 1))
                  for backend in backends}
        pids = {backend: node_pids(graph) for backend, graph in graphs.items()}
        cpu = {backend: node_report(pids[backend]["planner"], Path(folder))["seconds"] for backend in backends}
        for backend in backends:  # forget the warm-up rollouts
            node_report(pids[backend]["scenario_player"], Path(folder))
        embedded = {"gap": [], "plan": [], "rollout": [], "cpu": [0.0]}
        steps = {backend: {step: [] for step in (*STEPS, "gap", "plan", "ratio")} for backend in backends}
        used = dict.fromkeys(backends, 0.0)
        for _ in range(rollouts):
            plan_timer.forget()
            before = plan_timer.tally()[1]
            started = time.perf_counter()
            stack.rollout(errors)
            embedded["rollout"].append(time.perf_counter() - started)
            embedded["cpu"][0] += plan_timer.tally()[1] - before
            calls = plan_timer.plans()
            embedded["gap"] += embedded_gaps(calls)
            embedded["plan"] += [end - start for start, end in calls]
            for backend, graph in graphs.items():
                started = time.perf_counter()
                graph.rollout(errors)
                steps[backend]["ratio"].append((time.perf_counter() - started) / embedded["rollout"][-1])
                planner, player = (node_report(pids[backend][node], Path(folder))
                                   for node in ("planner", "scenario_player"))
                for step, seconds in graph_gaps(planner, player, profile.plan.topic, profile.ego_topic).items():
                    steps[backend][step] += seconds
                steps[backend]["plan"] += [end - start for start, end in planner["plans"]]
                used[backend] += planner["seconds"] - cpu[backend]
                cpu[backend] = planner["seconds"]
    print(f"embedded  gap between two plan() calls: median {statistics.median(embedded['gap']) * 1e6:6.0f} us, "
          f"mean {statistics.fmean(embedded['gap']) * 1e6:6.0f} us; plan() {statistics.fmean(embedded['plan']) * 1e3:.2f} "
          f"ms a frame, {embedded['cpu'][0] / len(embedded['plan']) * 1e3:.2f} ms of CPU")
    for backend, measured in steps.items():
        print(f"{backend}:")
        for step in (*STEPS, "gap"):
            label = "the gap, all five" if step == "gap" else step
            print(f"  {label:48s} median {statistics.median(measured[step]) * 1e6:6.0f} us, "
                  f"mean {statistics.fmean(measured[step]) * 1e6:6.0f} us")
        extra = statistics.fmean(measured["gap"]) - statistics.fmean(embedded["gap"])
        print(f"  plan() {statistics.fmean(measured['plan']) * 1e3:.2f} ms a frame, "
              f"{used[backend] / len(measured['plan']) * 1e3:.2f} ms of CPU; the gap adds {extra * 1e3:.2f} ms a "
              f"frame to the embedded rollout's ({extra / statistics.fmean(embedded['plan']) * 100:.1f}% of a plan); "
              f"rollout / embedded (paired) median {statistics.median(measured['ratio']):.3f}x")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario", nargs="?", default="obp_overtake")
    parser.add_argument("--rollouts", type=int, default=3)
    parser.add_argument("--domain-id", type=int, default=184)
    options = parser.parse_args()
    keep_freed_heap()  # as `advperc attack` and the nodes do
    print(f"== {options.scenario}: {options.rollouts} ground-truth rollouts on each, in turn; {load_average()} ==")
    frame_gap(options.scenario, options.rollouts, options.domain_id)

