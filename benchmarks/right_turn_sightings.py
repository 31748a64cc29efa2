"""Is the paper's NDS-t of 0.98 out of reach on obp_right_turn? A bound and the test of its premise.

Every collision two 250-rollout guided searches found there (7 of 500 rollouts) showed car 1 (the
car the ego yields to) at least 2 m off, or not at all, in every frame up to the collision. If
every collision must, the score has a bound: car 1 is then unmatched at the 0.5, 1 and 2 m
thresholds in every scored frame, so recall there is at most r = 1 - (car 1's object-frames / all
counted ones); nuScenes' AP interpolates precision at 101 recall points and averages those above
the recall floor after taking off the precision floor, so AP <= (points in (floor, r]) / (points
above the floor); with AP <= 1 at 4 m and every TP error >= 0, NDS <= (5 x mean AP bound + 5) / 10,
and with the longest drop fraction >= 0, NDS-t <= (NDS bound + 1) / 2. Printed for the collision
frame of car 1's whole-track drop and, on the ground truth's ego path, for any later one.

The premise is then tested where it is weakest, one frame at a time: car 1's whole-track drop
(which collides at frame c) with car 1 shown in a single frame k < c, perfectly and 0.95 m (under
the 1 m threshold) ahead of, behind, left and right of itself. Printed per frame: the sightings
that keep the collision. Any one of them refutes the premise, and with it the bound.

    python benchmarks/right_turn_sightings.py [--workers 2]
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))  # measure this checkout, not whichever advperc_ros is installed

from advperc_ros.backends.embedded import Stack  # noqa: E402
from advperc_ros.configs import core_configs  # noqa: E402
from advperc_ros.core.perception_errors import PerceptionErrors  # noqa: E402
from advperc_ros.core.metrics.nds import (DIST_THRESHOLDS, TP_METRICS, TP_THRESHOLD, ap_bound,  # noqa: E402
                                          in_range, nds_score)
from advperc_ros.core.metrics.scores import nds_t_score  # noqa: E402
from advperc_ros.core.search.guided import AXES, displacement  # noqa: E402
from advperc_ros.params import load_params  # noqa: E402
from advperc_ros.ros.bag import read_scenario  # noqa: E402

SCENARIO = "obp_right_turn"
CAR = 1  # the agent id of the car the ego yields to
SHOWN_OFF = 0.95 * DIST_THRESHOLDS[1]  # m: a true positive at 1, 2 and 4 m


def nds_t_bound(counted: np.ndarray, slot: int) -> float:
    """NDS-t at most, when `slot` is unmatched within 2 m in every frame of `counted` ((F, G) bool)."""
    recall = 1.0 - counted[:, slot].sum() / counted.sum()
    strict = [t for t in DIST_THRESHOLDS if t <= TP_THRESHOLD]  # thresholds car 1 cannot be matched at
    mean_ap = (len(strict) * ap_bound(recall) + len(DIST_THRESHOLDS) - len(strict)) / len(DIST_THRESHOLDS)
    return nds_t_score(nds_score(mean_ap, len(TP_METRICS)), 0.0)  # every TP error 0, no drop


def shown_once(drop: PerceptionErrors, slot: int, frame: int, yaw: float, axis: int | None) -> PerceptionErrors:
    """The drop with car `slot` detected in `frame` alone: perfectly (axis None) or SHOWN_OFF along AXES[axis]."""
    out = drop.copy()
    out.fn[frame, slot] = False
    if axis is not None:
        out.dx[frame, slot], out.dy[frame, slot] = displacement(yaw, axis, SHOWN_OFF)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    scenario = read_scenario(REPO / "bags" / SCENARIO)
    stack = Stack(scenario, core_configs(load_params(REPO / "config" / f"{SCENARIO}.yaml").with_values(workers=args.workers)))
    agents = scenario.agents
    slot = next(j for j in range(agents.shape[1]) if scenario.agent_id(j) == CAR)
    started = time.perf_counter()
    truth, drop = PerceptionErrors.none(*agents.shape), PerceptionErrors.none(*agents.shape)
    drop.fn[:, slot] = True
    truth_rollout, dropped = stack.rollout_many([truth, drop])
    assert not truth_rollout.collided and dropped.collided, "the ground truth must pass and car 1's drop collide"
    c = dropped.num_frames
    frames = [k for k in range(c) if agents.valid[k, slot]]
    variants = [(k, axis) for k in frames for axis in (None, *range(len(AXES)))]
    results = stack.rollout_many([shown_once(drop, slot, k, agents.yaw[k, slot], axis) for k, axis in variants])
    stack.close()
    still = [(k, axis) for (k, axis), result in zip(variants, results) if result.collided]
    inconclusive = sum(bool(result.inconclusive) for result in results)
    names = ["perfectly", *(f"{SHOWN_OFF:.1f} m {name}" for name in ("ahead", "behind", "left", "right"))]
    print(f"car 1 hidden throughout collides at frame {c}; shown in one frame of {len(frames)} before it, "
          f"{len(variants)} rollouts ({', '.join(names)}): {len(still)} still collide, {inconclusive} inconclusive "
          f"({time.perf_counter() - started:.0f} s)")
    for k in frames:
        kept = [names[0 if axis is None else axis + 1] for kk, axis in still if kk == k]
        print(f"  frame {k}: {'still collides shown ' + ', '.join(kept) if kept else 'every sighting loses the collision'}")
    counted = in_range(agents.frames(c), dropped.ego_xy)
    print(f"collision at frame {c}: car 1 is {counted[:, slot].sum()} of {counted.sum()} counted object-frames; "
          f"NDS-t <= {nds_t_bound(counted, slot):.4f} (paper: 0.98)")
    on_truth = in_range(agents, truth_rollout.ego_xy)
    later = [nds_t_bound(on_truth[:f], slot) for f in range(c, scenario.num_frames + 1)]
    print(f"a collision at any frame {c}..{scenario.num_frames} on the ground truth's ego path, car 1 >= 2 m off "
          f"throughout: NDS-t <= {max(later):.4f} (at frame {c + int(np.argmax(later))})")


if __name__ == "__main__":
    main()
