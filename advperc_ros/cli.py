"""The `advperc` command: attack, make-bags, score.

Bad input (missing or malformed bag, wrong params, NaN in ground truth, unknown planner) ends with
one line `advperc: error: <file>: <field>: ...` on stderr, exit code 2, and nothing written.
"""

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

from advperc_ros.core.planners.base import PlannerError
from advperc_ros.core.scenario import ScenarioError
from advperc_ros.core.search.problem import GroundTruthFails
from advperc_ros.params import ParamsError, load_params
from advperc_ros.ros.bag import BagError

INPUT_ERRORS = (ParamsError, BagError, ScenarioError, PlannerError)
EXIT_INPUT = 2
EXIT_NOTHING_TO_ATTACK = 1


def _default_output(params_path: Path, seed: int) -> Path:
    base = Path("results") / f"{params_path.stem}-seed{seed}"
    candidate, n = base, 1
    while candidate.exists():
        n += 1
        candidate = base.with_name(f"{base.name}-{n}")
    return candidate


def cmd_attack(args: argparse.Namespace) -> int:
    from advperc_ros.attack import resolve_bag, run_attack
    from advperc_ros.results import write_results
    from advperc_ros.ros.bag import read_scenario

    params = load_params(args.params)
    if args.seed is not None:
        params = params.with_values(seed=args.seed)
    output = Path(args.output) if args.output else _default_output(Path(args.params), params["seed"])
    if output.exists():
        raise ParamsError(f"{output}: output folder exists already; choose another --output")
    bag_path = resolve_bag(params)
    scenario = read_scenario(bag_path)
    outcome = run_attack(scenario, params, progress=not args.quiet)
    report = write_results(output, outcome, bag_path)
    summary = {k: report.get(k) for k in ("scenario", "objective", "collision", "nds", "nds_t", "fn", "tp", "rollouts")}
    print(json.dumps(summary))
    print(f"results written to {output}", file=sys.stderr)
    return 0


def cmd_make_bags(args: argparse.Namespace) -> int:
    from advperc_ros.core.scenario_spec import load_scenario_spec
    from advperc_ros.ros.bag import write_ground_truth_bag

    specs = [Path(p) for p in args.scenarios] or sorted(Path("scenarios").glob("*.yaml"))
    if not specs:
        raise ScenarioError("scenarios/: no scenario descriptions given or found")
    scenarios = [load_scenario_spec(spec) for spec in specs]  # validate all before writing any
    out_dir = Path(args.output_dir)
    for scenario in scenarios:
        target = out_dir / scenario.name
        if target.exists():
            if not args.force:
                raise BagError(f"{target}: exists already (use --force to rewrite)")
            shutil.rmtree(target)
        write_ground_truth_bag(target, scenario)
        print(f"{target}: {scenario.num_frames} frames, {scenario.agents.shape[1]} agents")
    return 0


def cmd_score(args: argparse.Namespace) -> int:
    from advperc_ros.core.metrics.scores import score
    from advperc_ros.ros.bag import GROUND_TRUTH, ODOMETRY, read_objects, read_topics
    from advperc_ros.ros.messages import odometry_to_ego, stamp_ns

    gt_stamps, truth = read_objects(Path(args.ground_truth), GROUND_TRUTH)
    pred_stamps, perceived = read_objects(Path(args.perceived), args.topic)
    common = np.intersect1d(gt_stamps, pred_stamps)
    if common.size == 0:
        raise BagError(f"{args.perceived}: topic '{args.topic}' shares no header.stamp with {args.ground_truth}")
    odometry = []
    for source in (Path(args.perceived), Path(args.ground_truth)):
        odometry = read_topics(source, [ODOMETRY])[0][ODOMETRY]
        if odometry:
            break
    if not odometry:
        raise BagError(f"{args.perceived}: topic '{ODOMETRY}' is missing in both bags (needed for the 50 m range)")
    odo_stamps = np.array([stamp_ns(m.header.stamp) for _, m in odometry])
    odo_xy = np.array([[odometry_to_ego(m).x, odometry_to_ego(m).y] for _, m in odometry])
    latest = np.clip(np.searchsorted(odo_stamps, common, side="right") - 1, 0, len(odometry) - 1)
    gt_rows = np.searchsorted(gt_stamps, common)
    pred_rows = np.searchsorted(pred_stamps, common)
    truth_frames = truth.select(gt_rows)
    perceived_frames = perceived.select(pred_rows)
    if np.any(np.isnan(perceived_frames.score[perceived_frames.valid])):
        raise BagError(f"{args.perceived}: topic '{args.topic}': field 'text' (confidence) is empty on some markers")
    result = score(truth_frames, perceived_frames, odo_xy[latest])
    print(json.dumps({"frames": int(common.size), **result.as_dict()}, indent=2))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="advperc", description="Adversarial perception error search.")
    sub = parser.add_subparsers(dest="command", required=True)

    attack = sub.add_parser("attack", help="search for an adversarial perception attack (embedded, no ROS needed)")
    attack.add_argument("params", help="params YAML in the ROS layout (orchestrator: ros__parameters: ...)")
    attack.add_argument("--output", help="results folder to create (default results/<params>-seed<N>)")
    attack.add_argument("--seed", type=int, help="override the params file's seed")
    attack.add_argument("--quiet", action="store_true", help="no progress bar")
    attack.set_defaults(func=cmd_attack)

    make_bags = sub.add_parser("make-bags", help="write ground-truth bags from scenario descriptions")
    make_bags.add_argument("scenarios", nargs="*", help="scenario YAML files (default scenarios/*.yaml)")
    make_bags.add_argument("--output-dir", default="bags", help="where to write the bags (default bags/)")
    make_bags.add_argument("--force", action="store_true", help="rewrite bags that exist")
    make_bags.set_defaults(func=cmd_make_bags)

    score_cmd = sub.add_parser("score", help="perception metrics of a perceived bag against ground truth, as JSON")
    score_cmd.add_argument("ground_truth", help="ground-truth bag (topic /ground_truth/objects)")
    score_cmd.add_argument("perceived", help="bag with detections (confidence in each CUBE marker's text)")
    score_cmd.add_argument("--topic", default="/perception/objects", help="detections topic in the perceived bag")
    score_cmd.set_defaults(func=cmd_score)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except INPUT_ERRORS as exc:
        print(f"advperc: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except GroundTruthFails as exc:
        print(f"advperc: {exc}", file=sys.stderr)
        return EXIT_NOTHING_TO_ATTACK


if __name__ == "__main__":
    sys.exit(main())
