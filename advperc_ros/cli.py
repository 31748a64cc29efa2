"""The `advperc` command: attack, make-bags, import-commonroad, import-bag, check-typical, robustness, pem fit, score.

Bad input (missing or malformed bag, wrong params, NaN in ground truth, unknown planner) ends with
one line `advperc: error: <file>: <field>: ...` on stderr, exit code 2, and nothing written. A graph
backend that cannot start (`--backend graph`) ends the same way with exit code 4.
"""

import argparse
import json
import logging
import math
import os
import shutil
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from advperc_ros.arguments import (
    OneLineParser,
    count,
    error_kinds,
    pathname,
    radii,
    strengths,
)
from advperc_ros.configs import core_configs
from advperc_ros.core.perception_errors import ERROR_KINDS, PAPER_KINDS
from advperc_ros.core.perception_errors.restriction import (
    DEFAULT_ITERATIONS,
    DEFAULT_RADII,
)
from advperc_ros.core.perception_errors.restriction import DEFAULT_KINDS as DEFAULT_REQUIREMENT_KINDS
from advperc_ros.core.robustness import DEFAULT_STRENGTHS
from advperc_ros.core.rules.registry import RULES
from advperc_ros.core.scenario import Scenario
from advperc_ros.core.search.problem import OBJECTIVES
from advperc_ros.core.search.registry import METHODS as SEARCH_METHODS
from advperc_ros.exceptions import (
    BagError,
    OutputError,
    ParamsError,
    RequirementSearchFailed,
    ResultsError,
    ScenarioError,
    ScenarioRejected,
)
from advperc_ros.exits import EXIT_INPUT, EXIT_INTERRUPTED, EXIT_NOTHING_TO_ATTACK, EXIT_OK, EXPECTED_TYPES, expected_failure
from advperc_ros.heap import keep_freed_heap
from advperc_ros.params import load_params


def cmd_attack(args: argparse.Namespace) -> int:
    from advperc_ros.application import attack_to_folder, backend_log, summary

    params = load_params(args.params)
    overrides = {"seed": args.seed, "rollout_backend": args.backend, "objective": args.objective,
                 "search.method": args.method, "errors.kinds": args.errors, "rule.name": args.rule,
                 "traffic.reactive": args.reactive, "fork_memory": args.fork_memory}
    params = params.with_values(**{name: value for name, value in overrides.items() if value is not None})
    if args.resume is not None and args.output is not None and Path(args.resume) != Path(args.output):
        raise ParamsError(f"--resume {args.resume} and --output {args.output}: give the folder once")
    output = args.resume or args.output
    said = logging.StreamHandler(sys.stderr)
    said.setFormatter(logging.Formatter("advperc: %(message)s"))
    with backend_log(said):
        output, report = attack_to_folder(params, Path(output) if output else None, progress=not args.quiet,
                                          resume=args.resume is not None)
    print(json.dumps(summary(report)))
    print(f"results written to {output}", file=sys.stderr)
    return EXIT_OK


def cmd_make_bags(args: argparse.Namespace) -> int:
    from advperc_ros.core.scenario_spec import load_scenario_spec
    from advperc_ros.results.destination import check_output
    from advperc_ros.ros.bag import write_ground_truth_bag

    specs = [Path(p) for p in args.scenarios] or sorted(Path("scenarios").glob("*.yaml"))
    if not specs:
        raise ScenarioError("scenarios/: no scenario descriptions given or found")
    scenarios = [load_scenario_spec(spec) for spec in specs]  # validate all before writing any
    out_dir = Path(args.output_dir)
    for scenario in scenarios:  # every target checked before any is written
        target = out_dir / scenario.name
        if target.is_dir() and not target.is_symlink() and args.force:
            if not (target / "metadata.yaml").is_file():  # --force rewrites bags, never a folder of the user's
                raise OutputError(f"{target}: exists and is not a rosbag2 bag (no metadata.yaml): --force rewrites "
                               "bags only")
            check_output(target / "metadata.yaml", "bag")  # writable: the check a new bag folder gets
        elif target.exists() or target.is_symlink():
            raise OutputError(f"{target}: exists already" + (" (use --force to rewrite)" if target.is_dir() else ""))
        else:
            check_output(target, "bag folder")
    for scenario in scenarios:
        target = out_dir / scenario.name
        if target.exists():
            shutil.rmtree(target)
        write_ground_truth_bag(target, scenario)
        print(f"{target}: {scenario.num_frames} frames, {scenario.agents.shape[1]} agents")
    return 0


REACTIVE_PLUGIN = "advperc_ros.contrib.reactive:ReactivePlanner"
FISS_PLUGIN = "advperc_ros.contrib.fiss:FissPlanner"


def _write_imported(command: str, source: str, scenario: Scenario, params_of: Callable[[str, str], dict],
                    planners: dict[str, str],
                    output: str | None, params: str | None) -> dict[str, Path]:
    """What both importers write, once every target is checked and the scenario is escapable: the
    ground-truth bag (default bags/<name>) and one params file per planner (`planners`: planner ->
    suffix of the file's stem, "" for the first, default <bag>.yaml). The params files by planner."""
    import yaml

    from advperc_ros.core.feasibility import unavoidable_collision
    from advperc_ros.params import SCHEMA
    from advperc_ros.results.destination import check_output
    from advperc_ros.ros.bag import write_ground_truth_bag

    reason = unavoidable_collision(scenario, SCHEMA["ego.length"].default, SCHEMA["ego.width"].default)
    if reason is not None:
        raise ScenarioRejected(f"{source}: rejected, not attacked: {reason}")
    bag = Path(output) if output else Path("bags") / scenario.name
    first = Path(params) if params else bag.with_name(f"{bag.name}.yaml")
    files = {planner: first.with_name(f"{first.stem}{suffix}{first.suffix}") for planner, suffix in planners.items()}
    for target in (bag, *files.values()):
        check_output(target, "bag folder" if target == bag else "params file")  # first: a name too long to look up
        if target.exists():
            raise OutputError(f"{target}: exists already, not overwriting")
    write_ground_truth_bag(bag, scenario)
    for planner, path in files.items():
        path.parent.mkdir(parents=True, exist_ok=True)
        document = params_of(str(bag.resolve()), planner)
        path.write_text(f"# generated by advperc {command} from {source}\n" + yaml.safe_dump(document))
    return files


def cmd_import_commonroad(args: argparse.Namespace) -> int:
    from advperc_ros.importers.commonroad import import_commonroad

    imported = import_commonroad(Path(args.scenario))
    scenario = imported.scenario
    # one params file per bundled planner and one per third-party plug-in (extras `reactive` and `fiss`), all
    # with the goal's target speed, the others beside IDM's
    files = _write_imported("import-commonroad", args.scenario, scenario, imported.params,
                            {"idm": "", "obp": ".obp", REACTIVE_PLUGIN: ".reactive", FISS_PLUGIN: ".fiss"},
                            args.output, args.params)
    bag = Path(args.output) if args.output else Path("bags") / scenario.name
    print(
        f"{bag}: {scenario.num_frames} frames, {scenario.agents.shape[1]} agents; route: {imported.route_note}\n"
        f"attack it with: advperc attack {files['idm']} (IDM), advperc attack {files['obp']} (ObP) or advperc attack "
        f"{files[REACTIVE_PLUGIN]} (commonroad-reactive-planner, extra 'reactive') or advperc attack {files[FISS_PLUGIN]} "
        f"(fiss-planner's FISS+, extra 'fiss'; planner_params.variant: fop, fop_plus, fiss, fiss_plus)"
    )
    return 0


def cmd_import_bag(args: argparse.Namespace) -> int:
    from advperc_ros.ros.drive_log import import_drive

    imported = import_drive(Path(args.log), args.objects, args.odometry, args.dt)
    scenario = imported.scenario
    files = _write_imported("import-bag", args.log, scenario, imported.params, {"idm": "", "obp": ".obp"},
                            args.output, args.params)
    bag = Path(args.output) if args.output else Path("bags") / scenario.name
    print(f"{bag}: {scenario.num_frames} frames of {scenario.dt:g} s, {scenario.agents.shape[1]} agents from "
          f"{imported.objects_topic}, ego from {imported.odometry_topic}, road from {imported.road}\n"
          f"attack it with: advperc attack {files['idm']} (IDM) or advperc attack {files['obp']} (ObP)")
    return 0


def cmd_check_typical(args: argparse.Namespace) -> int:
    from advperc_ros.backends.embedded import Stack
    from advperc_ros.core.pem import PEM, default_pem
    from advperc_ros.core.typical import check_typical
    from advperc_ros.params import resolve_bag
    from advperc_ros.ros.bag import read_scenario

    params = load_params(args.params)
    configs = core_configs(params)
    # the default for the kinds the params' attack may use: beyond the paper's, the calibrated model with every term
    pem = PEM.load(Path(args.model)) if args.model else default_pem(configs.search.errors.kinds)
    scenario = read_scenario(resolve_bag(params))
    stack = Stack(scenario, configs)
    result = check_typical(scenario, stack.rollout, pem, args.samples, np.random.default_rng(args.seed))
    print(json.dumps({"scenario": scenario.name, **result.__dict__, "passed": result.passed}))
    return 0 if result.passed else EXIT_NOTHING_TO_ATTACK


def cmd_robustness(args: argparse.Namespace) -> int:
    import csv
    from dataclasses import asdict, fields

    from advperc_ros.backends.embedded import Stack
    from advperc_ros.core.robustness import RobustnessPoint, robustness_curve
    from advperc_ros.core.search.problem import AttackProblem
    from advperc_ros.core.staging import staging_path
    from advperc_ros.results import plots
    from advperc_ros.results.destination import check_output
    from advperc_ros.results.folder import ERRORS, read_attack
    from advperc_ros.ros.bag import read_scenario

    results = Path(args.results)
    params, bag, errors = read_attack(results)
    table = results / "robustness.csv"
    check_output(table, "robustness table")  # a read-only results folder failed after all the rollouts
    scenario = read_scenario(bag)
    if errors.shape != scenario.agents.shape:
        raise ResultsError(f"{results / ERRORS}: field 'fn' has shape {errors.shape}, the bag {bag} has "
                           f"{scenario.agents.shape}")
    configs = core_configs(params)
    problem = AttackProblem(scenario, Stack(scenario, configs).rollout, params.objective,
                            kinds=configs.search.errors.kinds)
    points = robustness_curve(problem, errors, args.strengths, args.samples, np.random.default_rng(args.seed))
    staging = staging_path(table)
    with staging.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=[f.name for f in fields(RobustnessPoint)])
        writer.writeheader()
        writer.writerows(asdict(p) for p in points)
    plots.robustness(results / "robustness.png", points, params.objective)
    staging.rename(table)
    for p in points:
        print(f"strength {p.strength:5.2f}: {p.adversarial_fraction:5.2f} still collide, "
              f"mean {params.objective} {p.mean_metric:.4f}")
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from advperc_ros.replay import load_attack, replay, replay_params, replay_report, write_replay
    from advperc_ros.results.destination import check_output

    attack = load_attack(Path(args.results))
    params = replay_params(attack, load_params(args.params) if args.params else None)
    if args.backend is not None:
        params = params.with_values(rollout_backend=args.backend)
    if args.output:
        check_output(Path(args.output))
    replayed = replay(attack, params)
    report = write_replay(Path(args.output), replayed) if args.output else replay_report(replayed)
    keys = ("attack", "scenario", "objective", "rule", "attack_planner", "planner", "collision", "verdict",
            "min_signed_distance", "rule_value", "attack_min_signed_distance", "metric", "nds", "nds_t")
    print(json.dumps({key: report[key] for key in keys}))
    if args.output:
        print(f"replay written to {args.output}", file=sys.stderr)
    return EXIT_OK


def cmd_campaign(args: argparse.Namespace) -> int:
    from advperc_ros.campaign.run import run_campaign
    from advperc_ros.campaign.spec import load_campaign

    changes = {"output": args.output, "executor": args.executor, "workers": args.workers}
    campaign = load_campaign(args.campaign, **{field: value for field, value in changes.items() if value is not None})
    run = run_campaign(campaign, progress=not args.quiet)
    print(json.dumps(run.summary()))
    return run.exit_code


def cmd_requirements(args: argparse.Namespace) -> int:
    from advperc_ros.requirements import requirements_of

    try:
        brackets = requirements_of(args.params, Path(args.output), args.kinds, args.bins, args.iterations, args.budget,
                                   args.executor, args.workers, progress=not args.quiet, typical=args.typical)
    except RequirementSearchFailed as failed:
        print(f"advperc: {failed}", file=sys.stderr)
        return failed.exit_code if failed.exit_code is not None else 1
    print("\n".join(b.line() for b in brackets), file=sys.stderr)
    unattacked = sorted({b.scenario for b in brackets if b.ground_truth_breaks is not None})
    print(json.dumps({"output": args.output, "brackets": len(brackets), "broken": sum(b.breaks_at is not None for b in
                      brackets), "ground_truth_breaks_rule": unattacked}))
    return EXIT_NOTHING_TO_ATTACK if unattacked else EXIT_OK  # every other scenario's rows written all the same


def cmd_score(args: argparse.Namespace) -> int:
    from advperc_ros.core.metrics.scores import score
    from advperc_ros.core.pem import PEM, default_pem
    from advperc_ros.ros.bag import aligned_objects

    pem = PEM.load(Path(args.model)) if args.model else default_pem(args.errors)
    truth, perceived, ego_xy = aligned_objects(Path(args.ground_truth), Path(args.perceived), args.topic)
    result = score(truth, perceived, ego_xy, pem)
    scores = {name: value if not isinstance(value, float) or math.isfinite(value) else None  # JSON has no NaN
              for name, value in result.as_dict().items()}
    print(json.dumps({"frames": int(truth.shape[0]), **scores}, indent=2, allow_nan=False))
    return 0


def cmd_pem_fit(args: argparse.Namespace) -> int:
    from advperc_ros.core.pem_fit import fit_pem
    from advperc_ros.core.staging import staging_path
    from advperc_ros.importers.nuscenes import load_pairs
    from advperc_ros.results.destination import check_output
    from advperc_ros.ros.bag import aligned_objects

    check_output(Path(args.output), "model file")
    if args.nuscenes_gt:
        sources = [load_pairs(Path(args.nuscenes_gt), Path(results)) for results in args.inputs]
    else:
        gt = Path(args.ground_truth) if args.ground_truth else None
        sources = [aligned_objects(gt or Path(bag), Path(bag), args.topic) for bag in args.inputs]
    model, source = fit_pem(sources, args.inputs, tracked=not args.nuscenes_gt)  # a sample's slots are no agents
    output = Path(args.output)
    staging = staging_path(output)
    output.parent.mkdir(parents=True, exist_ok=True)  # check_output allowed folders still to be made
    model.save(staging)
    staging.rename(output)
    print(f"{output}: {source}")
    return 0


def cmd_check_bag(args: argparse.Namespace) -> int:
    """Every problem of a ground-truth bag, one line each (exit 2), or a short summary of it."""
    from advperc_ros.ros.bag import check_ground_truth

    check = check_ground_truth(Path(args.bag))
    for problem in check.problems:
        print(f"advperc: error: {problem}", file=sys.stderr)
    if check.problems:
        return EXIT_INPUT
    scenario = check.scenario
    if scenario is None:  # no problem found means the scenario was read
        raise BagError(f"{args.bag}: could not be read")
    topics = ", ".join(f"{name} ({count})" for name, (_, count) in sorted(check.topics.items()))
    print(f"{args.bag}: ok: '{scenario.name}', {scenario.num_frames} frames every {scenario.dt:.3f} s "
          f"({scenario.times[-1]:.3f} s), {scenario.agents.shape[1]} agents, {len(scenario.lanes)} lanes; topics: {topics}")
    return 0


def _import_bag_epilog() -> str:
    """What import-bag reads, listed from the interface profiles and the importer's own tables, so that
    the help names exactly the types the decoders take."""
    from advperc_ros.ros.drive_log import ODOMETRY_TOPICS, ODOMETRY_TYPE, object_layers
    from advperc_ros.ros.interfaces.registry import BUNDLED, load_profile
    from advperc_ros.ros.topics import LANES, ROUTE, TOPIC_TYPES

    lines = ["what it reads (topics are found by type, whatever their names):",
             "  objects (--objects), one topic of a type an interface profile (graph.interface) speaks:"]
    for name in BUNDLED:
        profile = load_profile(name)
        lines.append(f"    {name}: detections {profile.detections.msgtype}, tracks {profile.tracks.msgtype}")
    lines.append(f"  several objects topics: the first type present of {', '.join(object_layers())}")
    lines.append(f"  ego (--odometry): {ODOMETRY_TYPE}; of several, {' then '.join(ODOMETRY_TOPICS)}")
    lines.append(f"  road: {LANES} ({TOPIC_TYPES[LANES]}) and {ROUTE} ({TOPIC_TYPES[ROUTE]}) when the log has them, "
                 "else a corridor around the recorded ego path")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="advperc", description="Adversarial perception error search.")
    sub = parser.add_subparsers(dest="command", required=True)

    attack = sub.add_parser("attack", help="search for an adversarial perception attack (no ROS needed)")
    attack.add_argument("params", help="params YAML in the ROS layout (orchestrator: ros__parameters: ...)")
    attack.add_argument("--output", type=pathname, help="results folder to create (default results/<params>-seed<N>)")
    attack.add_argument("--seed", type=int, help="override the params file's seed")
    attack.add_argument("--objective", choices=OBJECTIVES, help="override the params file's objective")
    attack.add_argument("--errors", metavar="KINDS", help="override the params file's errors.kinds: paper, all, or a "
                        "comma-separated list of " + ", ".join(ERROR_KINDS))
    attack.add_argument("--method", choices=SEARCH_METHODS, help="override the params file's search.method (paper: the "
                        "paper's Algorithms 1 and 2, for reproducing it)")
    attack.add_argument("--rule", choices=tuple(RULES), metavar="RULE", help="override the params file's rule.name: the "
                        "driving rule to attack (docs/rules.md): " + ", ".join(RULES))
    attack.add_argument("--reactive", action="store_const", const=True, help="override the params file's "
                        "traffic.reactive: agents keep their recorded paths but brake for the ego (docs/traffic.md)")
    attack.add_argument("--fork-memory", type=int, metavar="MB", help="override the params file's fork_memory: MB of "
                        "snapshots each process keeps to fork rollouts from (0: every rollout from frame 0)")
    attack.add_argument("--quiet", action="store_true", help="no progress bar")
    attack.add_argument("--resume", metavar="OUTPUT", type=pathname,
                        help="finish the interrupted attack whose results folder was to be "
                        "OUTPUT (same params): rollouts already run are not run again, and the report is the one an "
                        "uninterrupted run writes")
    attack.add_argument("--backend", choices=("embedded", "graph"),
                        help="override rollout_backend: embedded (one process) or graph (the nodes over Cyclone DDS)")
    attack.set_defaults(func=cmd_attack)

    make_bags = sub.add_parser("make-bags", help="write ground-truth bags from scenario descriptions")
    make_bags.add_argument("scenarios", nargs="*", help="scenario YAML files (default scenarios/*.yaml)")
    make_bags.add_argument("--output-dir", type=pathname, default="bags", help="where to write the bags (default bags/)")
    make_bags.add_argument("--force", action="store_true", help="rewrite bags that exist")
    make_bags.set_defaults(func=cmd_make_bags)

    importer = sub.add_parser("import-commonroad", help="CommonRoad scenario of recorded traffic -> ground-truth bag")
    importer.add_argument("scenario", help="CommonRoad XML file")
    importer.add_argument("--output", type=pathname, help="bag directory to write (default bags/<scenario id>)")
    importer.add_argument("--params", type=pathname, help="params file to write for attacking it (default <output>.yaml)")
    importer.set_defaults(func=cmd_import_commonroad)

    drive = sub.add_parser("import-bag", help="a recorded drive (rosbag2 log: objects + odometry) -> ground-truth bag",
                           epilog=_import_bag_epilog(), formatter_class=argparse.RawDescriptionHelpFormatter)
    drive.add_argument("log", help="rosbag2 bag directory (MCAP, or sqlite3) of your own drive")
    drive.add_argument("--objects", help="objects topic (default: the only one of a type an interface profile speaks)")
    drive.add_argument("--odometry", help="nav_msgs/Odometry topic of the ego (default: the only one)")
    drive.add_argument("--dt", type=float, default=0.1, help="frame period to resample to, s (default 0.1)")
    drive.add_argument("--output", type=pathname, help="bag directory to write (default bags/<log name>)")
    drive.add_argument("--params", type=pathname, help="params file to write for attacking it (default <output>.yaml)")
    drive.set_defaults(func=cmd_import_bag)

    typical = sub.add_parser("check-typical", help="roll out PEM-sampled typical errors; exit 1 on any collision")
    typical.add_argument("params", help="params YAML, as for attack")
    typical.add_argument("--samples", type=count, default=100, help="rollouts (paper: 100)")
    typical.add_argument("--seed", type=int, default=0)
    typical.add_argument("--model", type=pathname, help="PEM JSON (default: the shipped model for the params' errors.kinds: "
                         "the hand-specified one for the paper's kinds, the calibrated one with every term beyond)")
    typical.set_defaults(func=cmd_check_typical)

    robust = sub.add_parser("robustness", help="perturb a found attack at growing strength (paper figure 5)")
    robust.add_argument("results", help="results folder of an attack (report.json + attack_errors.npz)")
    robust.add_argument("--strengths", type=strengths, default=DEFAULT_STRENGTHS,
                        help="comma-separated strengths in [0, 1]")
    robust.add_argument("--samples", type=count, default=10, help="perturbations per strength (paper: 10)")
    robust.add_argument("--seed", type=int, default=0)
    robust.set_defaults(func=cmd_robustness)

    campaign = sub.add_parser("campaign", help="attack scenarios x objectives x seeds x rules x planners (or replay found "
                              "attacks) into one table, JUnit XML included; resumable")
    campaign.add_argument("campaign", help="campaign YAML (see the README's Campaigns)")
    campaign.add_argument("--output", type=pathname, help="override the campaign's output folder")
    campaign.add_argument("--executor", choices=("process", "ray", "serial"), help="override the campaign's executor")
    campaign.add_argument("--workers", type=int, help="override the campaign's workers")
    campaign.add_argument("--quiet", action="store_true", help="no progress bar, no per-cell lines")
    campaign.set_defaults(func=cmd_campaign)

    needs = sub.add_parser("requirements", help="how good perception must be for the planner: per error kind and "
                           "distance from the ego, the largest error the search cannot break the rule with, and the "
                           "attack that breaks the next (docs/requirements.md); resumable")
    needs.add_argument("params", nargs="+", help="params YAML of each scenario, as for attack")
    needs.add_argument("--output", required=True, type=pathname, help="folder to write (requirements.json, .md, plots, "
                       "noise.yaml, a results folder per search); the same command resumes it")
    needs.add_argument("--kinds", default=",".join(DEFAULT_REQUIREMENT_KINDS),
                       help="comma-separated kinds to bound: drop, position, yaw, velocity, size, latency, or all "
                       f"(default {','.join(DEFAULT_REQUIREMENT_KINDS)})")
    needs.add_argument("--bins", type=radii, default=DEFAULT_RADII, help="the distance bins' outer radii in m, "
                       "increasing, the first bin from the ego (default 20,40,60)")
    needs.add_argument("--iterations", type=int, default=DEFAULT_ITERATIONS,
                       help=f"halvings of each bracket after its largest magnitude broke (default {DEFAULT_ITERATIONS})")
    needs.add_argument("--typical", type=int, default=10, help="PEM samples rolled out at each tolerated level (0: none)")
    needs.add_argument("--budget", type=count, help="rollouts of each search (search.budget; default the params')")
    needs.add_argument("--executor", choices=("process", "ray", "serial"), default="process",
                       help="where the searches of a round run (default process)")
    needs.add_argument("--workers", type=count, default=os.cpu_count() or 1, help="searches at once (default: CPUs)")
    needs.add_argument("--quiet", action="store_true", help="no progress bar")
    needs.set_defaults(func=cmd_requirements)

    replay_cmd = sub.add_parser("replay", help="re-run a found attack's errors against another planner or configuration")
    replay_cmd.add_argument("results", help="results folder of an attack that collided (report.json + attack_errors.npz)")
    replay_cmd.add_argument("--params", type=pathname,
                            help="params YAML of the planner or configuration to replay against (same bag); "
                            "default: the attack's own")
    replay_cmd.add_argument("--output", type=pathname,
                            help="replay folder to write (replay.json, replay.md, bev.png); default: none")
    replay_cmd.add_argument("--backend", choices=("embedded", "graph"), help="override rollout_backend")
    replay_cmd.set_defaults(func=cmd_replay)

    pem = sub.add_parser("pem", help="perception error model tools")
    pem_sub = pem.add_subparsers(dest="pem_command", required=True)
    pem_fit = pem_sub.add_parser("fit", help="fit a PEM to detections paired with ground truth")
    pem_fit.add_argument("inputs", nargs="+", help="bags with detections (and ground truth, unless --ground-truth), "
                         "or nuScenes detection-results JSON files with --nuscenes-gt")
    pem_fit.add_argument("--ground-truth", help="one ground-truth bag for all the detection bags")
    pem_fit.add_argument("--nuscenes-gt", help="nuScenes ground-truth boxes JSON (devkit-serialised, with ego_translation)")
    pem_fit.add_argument("--topic", default="/perception/objects", help="detections topic")
    pem_fit.add_argument("--output", required=True, type=pathname, help="model JSON to write")
    pem_fit.set_defaults(func=cmd_pem_fit)

    score_cmd = sub.add_parser("score", help="perception metrics of a perceived bag against ground truth, as JSON")
    score_cmd.add_argument("ground_truth", help="ground-truth bag (topic /ground_truth/objects)")
    score_cmd.add_argument("perceived", help="bag with detections (confidence in each CUBE marker's text)")
    score_cmd.add_argument("--topic", default="/perception/objects", help="detections topic in the perceived bag")
    score_cmd.add_argument("--errors", metavar="KINDS", type=error_kinds, default=PAPER_KINDS,
                           help="score PEM LL with the shipped model for these kinds, as an attack with this "
                           "errors.kinds did (paper: the hand-specified one; any kind beyond: the calibrated one)")
    score_cmd.add_argument("--model", type=pathname, help="PEM JSON to score PEM LL with instead (overrides --errors)")
    score_cmd.set_defaults(func=cmd_score)

    check_bag = sub.add_parser("check-bag", help="check a ground-truth bag against the bag contract")
    check_bag.add_argument("bag", help="ground-truth bag directory")
    check_bag.set_defaults(func=cmd_check_bag)
    return parser


def main(argv: list[str] | None = None) -> int:
    keep_freed_heap()
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except EXPECTED_TYPES as exc:
        line, code = expected_failure(exc)
        print(f"advperc: {line}", file=sys.stderr)
        return code
    except KeyboardInterrupt:  # outside an attack: nothing to finish
        print("advperc: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
