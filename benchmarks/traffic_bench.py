"""What reactive traffic costs a rollout: the same rollouts replayed and reactive, side by side (docs/traffic.md).

Per scenario (a bundled config, or a CommonRoad recording imported into a temporary folder), the ground
truth's rollout and one with the lead hidden, each under replayed and reactive traffic in turn, `--repeats`
times; prints per scenario the median wall time of each and their ratio (pairs run back to back, as the
machine's speed drifts), the agents, and the largest resident set the process reached.

    python benchmarks/traffic_bench.py
    python benchmarks/traffic_bench.py --scenarios idm_lane_following --recordings USA_US101-22_1_T-1 --repeats 5
"""

import argparse
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from advperc_ros.backends.embedded import Stack
from advperc_ros.configs import core_configs
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.traffic import IDMParameters
from advperc_ros.params import load_params, resolve_bag
from advperc_ros.ros.bag import read_scenario

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data" / "commonroad"
BUNDLED = ("idm_lane_following", "idm_overtake_follow", "obp_overtake")


def stacks(params_path: Path) -> tuple[Stack, Stack]:
    """(replayed, reactive) stacks of one params file, the planner built once each."""
    params = load_params(params_path)
    scenario = read_scenario(resolve_bag(params))
    configs = core_configs(params)
    reactive = replace(configs, rollout=replace(configs.rollout, traffic=IDMParameters()))
    return Stack(scenario, configs), Stack(scenario, reactive)


def timed(stack: Stack, errors: PerceptionErrors) -> float:
    started = time.perf_counter()
    stack.rollout(errors)
    return time.perf_counter() - started


def measure(name: str, params_path: Path, repeats: int) -> None:
    replayed, reactive = stacks(params_path)
    scenario = replayed.scenario
    none = PerceptionErrors.none(*scenario.agents.shape)
    tensors = [none, none.with_drop(0, scenario.num_frames // 5, scenario.num_frames - 1)]
    times: dict[str, list[float]] = {"replayed": [], "reactive": []}
    ratios = []
    for _ in range(repeats):
        for errors in tensors:
            a, b = timed(replayed, errors), timed(reactive, errors)
            times["replayed"].append(a)
            times["reactive"].append(b)
            ratios.append(b / a)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"| {name} | {scenario.agents.shape[1]} | {scenario.num_frames} | {statistics.median(times['replayed']):.3f} | "
          f"{statistics.median(times['reactive']):.3f} | {statistics.median(ratios):.2f}x | {rss:.0f} |", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenarios", nargs="*", default=BUNDLED, help="bundled configs (config/<name>.yaml)")
    parser.add_argument("--recordings", nargs="*", default=(), help="CommonRoad recordings (file stems in --data)")
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print("| scenario | agents | frames | replayed (s) | reactive (s) | reactive / replayed | max RSS (MiB) |")
    print("|---|---|---|---|---|---|---|")
    for name in args.scenarios:
        measure(name, REPO / "config" / f"{name}.yaml", args.repeats)
    with tempfile.TemporaryDirectory(prefix="traffic-bench-") as scratch:
        for name in args.recordings:
            bag = Path(scratch) / name / "bag"
            subprocess.run([sys.executable, "-m", "advperc_ros.cli", "import-commonroad", str(args.data / f"{name}.xml"),
                            "--output", str(bag)], check=True, capture_output=True)
            measure(name, bag.with_name("bag.yaml"), args.repeats)


if __name__ == "__main__":
    main()
