"""Where a forked search drives its frames: per phase of the default search, how many frames its rollouts
drove of the frames they ran to, and from which frame (docs/results.md, "Forked rollouts").

A forked rollout drives from the first frame at which what the tracker is handed differs from an earlier
rollout's, to its end (the scenario's last frame, or the collision that ends it). So what forking saves is
set by where the search's candidates first differ: this prints it per phase, with the first frame at which
the attack found shows any error, which `fork_bench.py`'s ratio follows.

    python benchmarks/fork_phases.py obp_left_turn obp_right_turn
    python benchmarks/fork_phases.py --params DIR/bag.obp.yaml
"""

import argparse
import statistics
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from advperc_ros.application import run_attack
from advperc_ros.backends.embedded import Stack
from advperc_ros.configs import core_configs
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.rollout import RolloutResult
from advperc_ros.params import load_params, resolve_bag
from advperc_ros.ros.bag import read_scenario

REPO = Path(__file__).resolve().parent.parent


class CountingStack(Stack):
    """The embedded stack, noting of every rollout the frame it started from and the frames it ran to."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.spans: list[tuple[int, int]] = []  # (first frame driven, frames)

    def rollout(self, errors: PerceptionErrors, record: bool = False) -> RolloutResult:
        result = super().rollout(errors, record)
        self.spans.append((self.forks.last_fork or 0, result.num_frames))
        return result


def first_error_frame(errors: PerceptionErrors, frames: int) -> int | None:
    """The first frame at which the attack shows any object wrongly (a ghost included), None if none."""
    changed = np.zeros(frames, dtype=bool)
    blank = PerceptionErrors.none(*errors.shape, errors.kinds, errors.ghost_slots).arrays()
    for name, array in errors.arrays().items():
        differs = array[:frames] != blank[name][:frames]
        changed |= differs.reshape(frames, -1).any(axis=1)
    return int(np.argmax(changed)) if changed.any() else None


def phases(name: str, params_path: Path) -> None:
    """Print one search's table: per phase, its rollouts' frames driven and where they started."""
    params = load_params(params_path)
    scenario = read_scenario(resolve_bag(params))
    stack = CountingStack(scenario, core_configs(params))
    outcome = run_attack(scenario, params, progress=False, rollouts=stack)
    spans = stack.spans[: len(outcome.log)]  # the last rollout is the attack's recording
    by_phase: dict[str, list[tuple[int, int]]] = defaultdict(list)
    for row, span in zip(outcome.log, spans):
        by_phase[str(row.phase)].append(span)
    full = sum(frames for _, frames in spans)
    driven = sum(frames - first for first, frames in spans)
    attack = outcome.best.errors if outcome.best is not None else None
    starts = first_error_frame(attack, scenario.num_frames) if attack is not None else None
    collides = outcome.best.rollout.num_frames if outcome.best is not None else None
    print(f"\n{name}: {len(spans)} rollouts of {scenario.num_frames} frames, {driven} of {full} frames driven "
          f"({driven / max(full, 1):.2f}); the attack's errors start at frame {starts}, its rollout ends at frame "
          f"{collides}")
    print("| phase | rollouts | frames driven / their frames | share of all frames driven | median first frame "
          "driven | median frames run |")
    print("|---|---|---|---|---|---|")
    for phase, spent in by_phase.items():
        ran = sum(frames for _, frames in spent)
        drove = sum(frames - first for first, frames in spent)
        print(f"| {phase} | {len(spent)} | {drove / max(ran, 1):.2f} | {drove / max(driven, 1):.2f} | "
              f"{statistics.median(first for first, _ in spent):.0f} | {statistics.median(f for _, f in spent):.0f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenarios", nargs="*", default=("obp_overtake", "obp_left_turn", "obp_right_turn"),
                        help="bundled configs (config/<name>.yaml)")
    parser.add_argument("--params", nargs="*", type=Path, default=(), help="params files (a recording's, say)")
    args = parser.parse_args()
    jobs = [(name, REPO / "config" / f"{name}.yaml") for name in args.scenarios]
    jobs += [(str(path), path) for path in args.params]
    if not jobs:
        sys.exit("nothing to measure")
    for name, path in jobs:
        phases(name, path)


if __name__ == "__main__":
    main()
