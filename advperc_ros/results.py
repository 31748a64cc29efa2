"""The results folder of an attack: bag, report (JSON and Markdown), search log, plots.

Everything is written into a hidden staging folder that is renamed into place at the end, so an
interrupted run never leaves a folder that looks complete.
"""

import csv
import json
import math
import platform
from dataclasses import asdict, fields
from importlib import metadata
from pathlib import Path

import numpy as np

from advperc_ros import __version__
from advperc_ros.core.perception_errors import PerceptionErrors, inject
from advperc_ros.core.rollout import RolloutResult
from advperc_ros.core.scenario import EgoState
from advperc_ros.core.search.approach import Approach
from advperc_ros.core.search.problem import Evaluation, LogRow
from advperc_ros.core.staging import staged_folder
from advperc_ros.outcome import AttackOutcome
from advperc_ros.params import NODE, PLANNER_PARAMS, AttackParams, ParamsError, find_bag, nest, parse_params
from advperc_ros.ros import bag as bags
from advperc_ros.ros import cdr, topics
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.bag import BagError

REPORT_JSON = "report.json"
REPORT_MD = "report.md"
SEARCH_LOG = "search_log.csv"
BAG_DIR = "attack"  # rosbag2 directory: attack/attack.mcap + attack/metadata.yaml
METRIC_PLOT = "metric_vs_rollouts.png"
BEV_PLOT = "bev.png"
ANIMATION = "attack.gif"
FOXGLOVE_LAYOUT = "foxglove_layout.json"  # beside attack/: Foxglove's Layouts > Import from file
ERRORS = "attack_errors.npz"  # the error tensor e of the best attack, with agent ids and stamps
EGO_COLOR = (0.9, 0.15, 0.15, 1.0)  # RGBA in the Foxglove layout; objects keep the bag's colours (cdr.COLORS)
PLAN_COLOR = (1.0, 0.55, 0.0, 1.0)
WALL_CLOCK_FIELDS = ("wall_time_s",)
TRAJECTORY_FIELDS = ("min_signed_distance", "pem_ll", "metric")
"""Report floats that depend continuously on the ego trajectory. The graph backend's trajectory
differs from the embedded one in the last bits (messages carry yaw as a quaternion and velocity as
an arrow; docs/graph.md), so these are rounded to REPORT_DIGITS significant digits and both
backends write the same report. Every other float is the same to the bit in both."""
REPORT_DIGITS = 7
LIBRARIES = ("numpy", "scipy", "filterpy", "casadi", "rosbags", "mcap-ros2-support", "matplotlib")


def _finite_or_none(value: float) -> float | None:
    return None if value is None or (isinstance(value, float) and math.isnan(value)) else value


def rounded(name: str, value):
    """`value` as report.json holds it: trajectory-derived floats to REPORT_DIGITS (see above)."""
    if name in TRAJECTORY_FIELDS and isinstance(value, float) and math.isfinite(value):
        return float(f"{value:.{REPORT_DIGITS}g}")
    return value


def report_scores(evaluation: Evaluation) -> dict:
    """An evaluation's scores as report.json holds them (NaN as null, rounded as `rounded`)."""
    return {k: rounded(k, _finite_or_none(v)) for k, v in evaluation.scores.as_dict().items()}


def _ids(ids: list[int], shown: int = 10) -> str:
    text = ", ".join(str(i) for i in ids[:shown])
    return text + (f", ... ({len(ids)} in all)" if len(ids) > shown else "")


def why_no_collision(log: list[LogRow], blind: RolloutResult | None = None, approach: Approach | None = None) -> dict:
    """Why a search found nothing, from its log: the agents whose whole track was dropped (the heuristic
    refines only a drop that collides) and how close the ego came, hidden agent or not; from the
    joint drops' `blind` rollout (every vehicle hidden), whether any drop could matter; and how close
    the `approach` phase (cars shown displaced) brought the ego at its fault."""
    truth = next(row for row in log if row.phase == "ground_truth")  # the first rollout, always conclusive
    drops = [row for row in log if row.phase == "heuristic_drop"]
    conclusive = [row for row in drops if not row.inconclusive and math.isfinite(row.min_signed_distance)]
    inconclusive = [row for row in drops if row.inconclusive]
    if not drops:
        text = "no collision found: no agent to attack, the scenario has none"
    else:
        text = (f"no collision found: no agent is influential (dropping any one of the {len(drops)} agents "
                f"({_ids([r.agent for r in drops])}) for the whole scenario never made the ego collide), so the "
                f"heuristic had no failure to narrow and the search none to improve")
    if inconclusive:
        text += (f"; the drops of agents {_ids([r.agent for r in inconclusive])} were inconclusive "
                 f"({inconclusive[0].inconclusive})")
    nearest = min(conclusive, key=lambda row: row.min_signed_distance, default=truth)
    if nearest.min_signed_distance < truth.min_signed_distance:
        text += (f"; closest approach {nearest.min_signed_distance:.2f} m, with agent {nearest.agent} dropped "
                 f"(rollout {nearest.rollout}; perfect perception {truth.min_signed_distance:.2f} m)")
    else:
        nearest = truth
        text += (f"; {'no single drop brought the ego closer than perfect perception does: ' if conclusive else ''}"
                 f"closest approach {truth.min_signed_distance:.2f} m")
    blind_report = None
    if blind is not None:
        text += "; " + _blind_clause(blind)
        blind_report = {"collided": blind.collided, "inconclusive": blind.inconclusive,
                        "min_signed_distance": rounded("min_signed_distance", blind.min_signed_distance),
                        "margin": rounded("min_signed_distance", blind.margin)}
    approach_report = None
    if approach is not None:
        text += "; " + _approach_clause(approach)
        approach_report = {"rollouts": approach.rollouts,
                           "start_margin": rounded("min_signed_distance", approach.start.rollout.margin),
                           "closest_margin": rounded("min_signed_distance", approach.closest.rollout.margin)}
    return {
        "message": text,
        "blind": blind_report,
        "approach": approach_report,
        "agents_tried": [row.agent for row in drops],
        "closest_approach": {
            "min_signed_distance": rounded("min_signed_distance", nearest.min_signed_distance),
            "agent": nearest.agent if nearest.agent >= 0 else None,
            "rollout": nearest.rollout,
        },
        "closest_approach_by_agent": {
            str(row.agent): rounded("min_signed_distance", row.min_signed_distance) for row in conclusive
        },
        "ground_truth_min_signed_distance": rounded("min_signed_distance", truth.min_signed_distance),
    }


def _blind_clause(blind: RolloutResult) -> str:
    """What hiding every vehicle does, which tells whether missed detections can matter at all: an ego
    that stays clear of the recorded traffic even blind to it is not put in its way by hiding some. (A
    blind rollout that collides is an attack: the joint drops narrow it.)"""
    if blind.inconclusive is not None:
        return f"with every vehicle hidden at once the rollout was inconclusive ({blind.inconclusive})"
    at_fault = (f", {blind.margin:.2f} m where a contact would be its fault"
                if blind.margin != blind.min_signed_distance else "")
    return (f"even with every vehicle hidden at once the ego collides with none at its fault (closest approach "
            f"{blind.min_signed_distance:.2f} m{at_fault}): unseen, the recorded traffic still does not come into its way")


def _approach_clause(approach: Approach) -> str:
    """How near showing the cars nearest the ego wrongly brought it to a collision at its fault."""
    return (f"showing the cars nearest the ego displaced or hidden for a while ({approach.rollouts} rollouts of "
            f"the approach phase) "
            f"brought its margin to a collision at its fault from {approach.start.rollout.margin:.2f} m to "
            f"{approach.closest.rollout.margin:.2f} m")


def versions() -> dict[str, str]:
    out = {"advperc_ros": __version__, "python": platform.python_version()}
    for name in LIBRARIES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def build_report(outcome: AttackOutcome, bag_path: Path) -> dict:
    params = outcome.params
    best = outcome.best
    report = {
        "scenario": outcome.scenario.name,
        "bag": params.bag,
        "bag_sha256": bags.digest(bag_path),
        "planner": params.planner,
        "objective": params.objective,
        "seed": params.seed,
        "collision": best is not None,
        "min_signed_distance": None,
        "collision_frame": None,
        "collision_agent": None,
    }
    if outcome.planner_node is not None:
        report["planner_node"] = outcome.planner_node
    if best is not None:
        rollout = outcome.recorded
        frame, slot = rollout.closest_approach()
        report.update(
            min_signed_distance=rounded("min_signed_distance", rollout.min_signed_distance),
            collision_frame=frame,
            collision_agent=int(outcome.scenario.agents.ids[frame, slot]),
            **report_scores(best),
        )
    else:
        report.update(why_no_collision(outcome.log, outcome.joint.blind.rollout if outcome.joint else None,
                                       outcome.approach))
    if outcome.heuristic_best is not None:
        report["heuristic"] = {"metric": rounded("metric", outcome.heuristic_best.metric), **report_scores(outcome.heuristic_best)}
    # no single drop collided: the agents the joint drops' failure mode hides together ([]: none found)
    report["joint_agents"] = list(outcome.joint.agents) if outcome.joint is not None else None
    report.update(
        rollouts=len(outcome.log),
        inconclusive_rollouts=sum(1 for row in outcome.log if row.inconclusive),
        wall_time_s=outcome.wall_time_s,
        config_hash=params.config_hash(),
        params=params.canonical(),
        versions=versions(),
    )
    return report


def _fmt(value, digits: int = 2) -> str:
    return "N/A" if value is None else f"{value:.{digits}f}"


def _planner_label(report: dict) -> str:
    node = report.get("planner_node")
    return report["planner"] if node is None else f"{report['planner']} ({node or 'node name unknown'})"


def report_markdown(report: dict) -> str:
    title = f"# Attack on {report['scenario']} ({_planner_label(report)} planner, objective {report['objective']})"
    lines = [title, ""] + (_table(report) if report["collision"] else _no_collision(report)) + [
        "",
        f"- seed {report['seed']}, config hash {report['config_hash']}, {report['rollouts']} rollouts, "
        f"wall time {report['wall_time_s']:.1f} s",
        "",
    ]
    return "\n".join(lines)


def _table(report: dict) -> list[str]:
    lines = [
        "| Search | Total FN/TP | MPE (m) | MAOE (rad) | NDS | NDS-t | PEM LL | Rollouts |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, row, rollouts in (("heuristic", report["heuristic"], ""), (report["objective"], report, report["rollouts"])):
        lines.append(
            f"| {name} | {row['fn']}/{row['tp']} | {_fmt(row['mpe'])} | {_fmt(row['maoe'])} | "
            f"{_fmt(row['nds'], 4)} | {_fmt(row['nds_t'], 4)} | {_fmt(row['pem_ll'])} | {rollouts} |"
        )
    joint = report["joint_agents"]
    return lines + [
        "",
        f"- collision with agent {report['collision_agent']} at frame {report['collision_frame']}, "
        f"min signed distance {report['min_signed_distance']:.3f} m",
        *([f"- no single agent's drop collided: agents {_ids(joint)} dropped jointly"] if joint else []),
        "- TP/FN: ground-truth cars within 50 m matched / not matched at 4 m; MPE and MAOE over TPs",
    ]


def _no_collision(report: dict) -> list[str]:
    """Why there is no Table 1 row; the drops that brought the ego closer than perfect perception, nearest first."""
    lines = [f"{report['message'][0].upper()}{report['message'][1:]}."]
    closer = [(agent, distance) for agent, distance in report["closest_approach_by_agent"].items()
              if distance < report["ground_truth_min_signed_distance"]]
    by_agent = sorted(closer, key=lambda item: item[1])
    if by_agent:
        lines += ["", "| agent dropped (whole track) | closest approach (m) |", "|---|---|"]
        lines += [f"| {agent} | {distance:.2f} |" for agent, distance in by_agent[:10]]
        if len(by_agent) > 10:
            lines.append(f"| ... {len(by_agent) - 10} more, farther | |")
    return lines


def write_search_log(path: Path, log: list[LogRow]) -> None:
    names = [f.name for f in fields(LogRow)]
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=names)
        writer.writeheader()
        for row in log:
            writer.writerow({k: (f"{v:.10g}" if isinstance(v, float) else v) for k, v in asdict(row).items()})


def write_attack_bag(path: Path, outcome: AttackOutcome, summary: str) -> None:
    """Per frame: ground truth, perceived objects, tracks, ego odometry, plan and rule value."""
    scenario = outcome.scenario
    rollout = outcome.recorded
    perceived = inject(scenario.agents, outcome.best.errors)
    with bags.open_bag_for_writing(path) as bag:
        bags.write_scenario_static(bag, scenario)
        for k in range(rollout.num_frames):
            ns = int(scenario.stamps_ns[k])
            bag.write(topics.CLOCK, ns, cdr.encode_clock(ns))
            bag.write(topics.GROUND_TRUTH, ns, cdr.encode_objects(scenario.agents.frame(k), ns, "ground_truth"))
            bag.write(topics.ODOMETRY, ns, msgs.ego_to_cdr(_ego(rollout.ego[k]), ns))
            distance = float(rollout.rule[k])
            bag.write(topics.RULE, ns, cdr.encode_float64(distance))
            bag.write(topics.RULE_DIAGNOSTICS, ns, msgs.diagnostics_cdr(
                ns, "collision", "violated" if distance < 0 else "ok", {"min_signed_distance": repr(distance)},
                level=2 if distance < 0 else 0,
            ))
            bag.write(topics.PERCEPTION, ns, cdr.encode_objects(perceived.frame(k), ns, "perception"))
            if k < len(rollout.tracks):
                bag.write(topics.TRACKING, ns, cdr.encode_objects(rollout.tracks[k], ns, "tracking"))
            if k < len(rollout.plans):
                bag.write(topics.PLAN, ns, msgs.trajectory_cdr(rollout.plans[k], ns))
        bag.write(topics.SUMMARY, int(scenario.stamps_ns[rollout.num_frames - 1]), msgs.string(summary))


def _hex(rgba: tuple[float, ...]) -> str:
    return "#" + "".join(f"{round(255 * c):02x}" for c in rgba)


def foxglove_layout(target: tuple[float, float] = (0.0, 0.0)) -> dict:
    """A Foxglove layout for an attack bag: a top-down 3D panel over `target` (map frame) with each
    layer on its own topic in its own colour (the bag's marker colours), the collision rule over time
    and the JSON summary. config/foxglove_layout.json is this layout over the origin."""
    markers = {topics.GROUND_TRUTH: "ground_truth", topics.PERCEPTION: "perception", topics.TRACKING: "tracking",
               topics.LANES: "lanes"}
    layers = {topic: {"visible": True, "color": _hex(cdr.COLORS[kind]), "showOutlines": True}
              for topic, kind in markers.items()}
    layers[topics.ODOMETRY] = {"visible": True, "type": "arrow", "arrowScale": [4.0, 0.8, 0.8], "color": _hex(EGO_COLOR),
                               "showCovariance": False}
    layers[topics.PLAN] = {"visible": True, "type": "line", "lineWidth": 0.4,
                           "gradient": [_hex(PLAN_COLOR), _hex(PLAN_COLOR[:3] + (0.3,))]}
    layers[topics.ROUTE] = {"visible": True, "type": "line", "lineWidth": 0.15, "gradient": ["#80808080", "#80808080"]}
    three_d, plot, summary = "3D!attack", "Plot!collision_rule", "RawMessages!summary"
    return {
        "configById": {
            three_d: {
                "cameraState": {"perspective": False, "distance": 80.0, "phi": 0.0, "thetaOffset": 0.0,
                                "target": [0.0, 0.0, 0.0], "targetOffset": [float(target[0]), float(target[1]), 0.0],
                                "targetOrientation": [0.0, 0.0, 0.0, 1.0], "fovy": 45.0, "near": 0.5, "far": 5000.0},
                "followMode": "follow-none",
                "followTf": "map",
                "scene": {"backgroundColor": "#202020"},
                "transforms": {},
                "topics": layers,
                "layers": {},
                "foxglovePanelTitle": "attack: truth white, perceived green, tracks blue, ego red, plan orange",
            },
            plot: {
                "foxglovePanelTitle": f"{topics.RULE}: min signed distance (m), < 0 is a collision",
                "paths": [{"value": f"{topics.RULE}.data", "enabled": True, "timestampMethod": "receiveTime",
                           "label": "signed distance (m)", "color": _hex(EGO_COLOR)}],
                "showLegend": True,
                "isSynced": True,
            },
            summary: {"topicPath": f"{topics.SUMMARY}.data", "foxglovePanelTitle": "attack summary (report.json)"},
        },
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1.0},
        "layout": {"direction": "row", "first": three_d, "splitPercentage": 65,
                   "second": {"direction": "column", "first": plot, "second": summary, "splitPercentage": 50}},
    }


def write_foxglove_layout(path: Path, layout: dict) -> None:
    path.write_text(json.dumps(layout, indent=2) + "\n")


def write_errors(path: Path, outcome: AttackOutcome) -> None:
    errors = outcome.best.errors
    agents = outcome.scenario.agents
    slot_ids = agents.ids[agents.valid.argmax(axis=0), np.arange(agents.shape[1])]
    np.savez_compressed(
        path, dx=errors.dx, dy=errors.dy, dyaw=errors.dyaw, fn=errors.fn, agent_ids=slot_ids,
        stamps_ns=outcome.scenario.stamps_ns,
    )


def load_errors(path: Path) -> PerceptionErrors:
    """The error tensor of a results folder; one BagError line if the file is not one."""
    try:
        with np.load(path) as data:
            errors = PerceptionErrors(dx=data["dx"], dy=data["dy"], dyaw=data["dyaw"], fn=data["fn"].astype(bool))
    except (OSError, ValueError, KeyError, EOFError) as exc:
        raise BagError(f"{path}: not an error tensor (npz with dx, dy, dyaw, fn): {exc}") from None
    if not all(array.shape == errors.fn.shape and array.ndim == 2 for array in (errors.dx, errors.dy, errors.dyaw)):
        raise BagError(f"{path}: fields 'dx', 'dy', 'dyaw', 'fn' must be frames x agents arrays of one shape")
    return errors


def read_attack(results: Path) -> tuple[AttackParams, Path, PerceptionErrors]:
    """A results folder's params, bag (found as the attack found it; checked against the report's
    bag_sha256) and error tensor, from any working directory; one line for whatever is wrong."""
    report_path, errors_path = results / REPORT_JSON, results / ERRORS
    for needed in (report_path, errors_path):
        if not needed.is_file():
            raise ParamsError(f"{needed}: missing; this needs the results folder of an attack that collided")
    try:
        report = json.loads(report_path.read_text())
        flat = dict(report["params"])
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as exc:
        raise ParamsError(f"{report_path}: not the report of an attack (no 'params'): {exc}") from None
    planner_params = flat.pop(PLANNER_PARAMS, {})
    params = parse_params({NODE: {"ros__parameters": {**nest(flat), PLANNER_PARAMS: planner_params}}}, str(report_path))
    bag = find_bag(params.bag, None)
    if "bag_sha256" in report and bags.digest(bag) != report["bag_sha256"]:
        raise BagError(f"{bag}: not the bag {report_path} attacked (field 'bag_sha256' differs)")
    return params, bag, load_errors(errors_path)


def _ego(row: np.ndarray) -> EgoState:
    return EgoState(*(float(v) for v in row))


def write_results(output: Path, outcome: AttackOutcome, bag_path: Path) -> dict:
    """Write the whole folder atomically; returns the report."""
    from advperc_ros import plots

    with staged_folder(Path(output)) as staging:
        staging.mkdir()
        report = build_report(outcome, bag_path)
        text = json.dumps(report, indent=2, sort_keys=True)
        (staging / REPORT_JSON).write_text(text + "\n")
        (staging / REPORT_MD).write_text(report_markdown(report))
        write_search_log(staging / SEARCH_LOG, outcome.log)
        plots.metric_vs_rollouts(staging / METRIC_PLOT, outcome.log, outcome.params.objective)
        if outcome.best is not None:
            write_errors(staging / ERRORS, outcome)
            write_attack_bag(staging / BAG_DIR, outcome, text)
            frame, _ = outcome.recorded.closest_approach()
            write_foxglove_layout(staging / FOXGLOVE_LAYOUT, foxglove_layout(tuple(outcome.recorded.ego[frame, :2])))
            plots.birds_eye_view(staging / BEV_PLOT, outcome)
            plots.attack_animation(staging / ANIMATION, outcome)
    return report
