"""The results folder of an attack: bag, report (JSON and Markdown, built by `advperc_ros.results.report`),
search log, plots; and reading one back (`read_attack`).

Everything is written into a hidden staging folder that is renamed into place at the end, so an
interrupted run never leaves a folder that looks complete.
"""

import csv
import json
from collections.abc import Callable
from dataclasses import asdict, fields
from pathlib import Path

import numpy as np

from advperc_ros.core.perception_errors import PerceptionErrors, inject
from advperc_ros.core.rollout import true_agents
from advperc_ros.core.rules.registry import rule_class
from advperc_ros.core.rules.verdict import DEFAULT_RULE
from advperc_ros.core.scenario import EgoState
from advperc_ros.core.search.problem import LogRow
from advperc_ros.core.search.registry import method_class
from advperc_ros.core.staging import staged_folder
from advperc_ros.exceptions import BagError, ResultsError
from advperc_ros.params import NODE, PLANNER_PARAMS, AttackParams, find_bag, nest, parse_params
from advperc_ros.results.outcome import AttackOutcome
from advperc_ros.results.report import build_report, report_markdown
from advperc_ros.ros import bag as bags
from advperc_ros.ros import cdr, topics
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.interfaces.base import ObjectsLayer, PlanLayer, Profile
from advperc_ros.ros.interfaces.registry import load_profile

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


def write_search_log(path: Path, log: list[LogRow]) -> None:
    """search_log.csv: a row per rollout, with the attacked rule's value (`rule_value`) only when a rule beyond the
    contact rules was attacked: under the collision rule the log is the paper's, `min_signed_distance` its value."""
    judged = any(row.rule_value is not None for row in log)
    names = [f.name for f in fields(LogRow) if judged or f.name != "rule_value"]
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=names)
        writer.writeheader()
        for row in log:
            writer.writerow({k: (f"{v:.10g}" if isinstance(v, float) else v) for k, v in asdict(row).items() if k in names})


def stack_layers(profile: Profile) -> dict[str, ObjectsLayer | PlanLayer]:
    """The layers an attack bag also holds in a stack's own types (perception, tracking, plan): those of
    `profile` whose topic the bag contract does not already carry in ours."""
    layers: dict[str, ObjectsLayer | PlanLayer] = {"perception": profile.detections, "tracking": profile.tracks,
                                                   "plan": profile.plan}
    return {name: layer for name, layer in layers.items() if layer.topic not in topics.TOPIC_TYPES}


def write_attack_bag(path: Path, outcome: AttackOutcome, summary: str) -> None:
    """Per frame: ground truth (under reactive traffic the agents as they drove, and on /ground_truth/recorded
    their recording), perceived objects, tracks, ego odometry, plan, and every rule's value on a topic
    of its own (`topics.RULE_TOPICS`: the outcome's `attack_rules`, as report.json's `rules`; +inf where
    nothing can bring a rule near a violation), the collision rule's also in the diagnostics; under an
    interface profile of its own (`graph.interface`), the perceived objects, tracks, plan and ego also in the
    profile's types on its topics, so the team's own viewers and tools read the attack."""
    scenario = outcome.scenario
    rollout = outcome.attack_rollout
    rules = outcome.attack_rules
    if rules is None:
        raise ValueError(f"{scenario.name}: no ground-truth rollout to judge the attack's rules against")
    tracks, plans = rollout.tracks or [], rollout.plans or []
    agents = true_agents(rollout, scenario)  # under reactive traffic the agents as they drove, the recording beside them
    perceived = inject(agents, outcome.attack.errors)
    profile = load_profile(outcome.params.graph.interface)
    detections, tracked, planned = profile.detections, profile.tracks, profile.plan
    # (topic, type, frames it has, its payload at frame k stamped ns) of each layer outside the contract
    payloads: dict[str, tuple[int, Callable[[int, int], bytes]]] = {
        "perception": (rollout.num_frames, lambda k, ns: detections.encode(perceived.frame(k), ns, "perception")),
        "tracking": (len(tracks), lambda k, ns: tracked.encode(tracks[k], ns, "tracking")),
        "plan": (len(plans), lambda k, ns: planned.encode(plans[k], ns)),
    }
    extra = [(layer.topic, layer.msgtype, *payloads[name]) for name, layer in stack_layers(profile).items()]
    ego_too = profile.ego_topic != topics.ODOMETRY
    with bags.open_bag_for_writing(path) as bag:
        bags.write_scenario_static(bag, scenario)
        for k in range(rollout.num_frames):
            ns = int(scenario.stamps_ns[k])
            bag.write(topics.CLOCK, ns, cdr.encode_clock(ns))
            bag.write(topics.GROUND_TRUTH, ns, cdr.encode_objects(agents.frame(k), ns, "ground_truth"))
            if rollout.agents is not None:
                bag.write(topics.RECORDED_AGENTS, ns, cdr.encode_objects(scenario.agents.frame(k), ns, "recorded"))
            odometry = msgs.ego_to_cdr(_ego(rollout.ego[k]), ns)
            bag.write(topics.ODOMETRY, ns, odometry)
            if ego_too:
                bag.write(profile.ego_topic, ns, odometry, topics.TOPIC_TYPES[topics.ODOMETRY])
            for name, topic in topics.RULE_TOPICS.items():
                bag.write(topic, ns, cdr.encode_float64(float(rules[name].per_frame[k])))
            distance = float(rules["collision"].per_frame[k])
            bag.write(topics.RULE_DIAGNOSTICS, ns, msgs.diagnostics_cdr(
                ns, "collision", "violated" if distance < 0 else "ok", {"min_signed_distance": repr(distance)},
                level=2 if distance < 0 else 0,
            ))
            bag.write(topics.PERCEPTION, ns, cdr.encode_objects(perceived.frame(k), ns, "perception"))
            if k < len(tracks):
                bag.write(topics.TRACKING, ns, cdr.encode_objects(tracks[k], ns, "tracking"))
            if k < len(plans):
                bag.write(topics.PLAN, ns, msgs.trajectory_cdr(plans[k], ns))
            for topic, msgtype, frames, payload in extra:
                if k < frames:
                    bag.write(topic, ns, payload(k, ns), msgtype)
        bag.write(topics.SUMMARY, int(scenario.stamps_ns[rollout.num_frames - 1]), msgs.string(summary))


def _hex(rgba: tuple[float, ...]) -> str:
    return "#" + "".join(f"{round(255 * c):02x}" for c in rgba)


def _column(panels: list) -> str | dict:
    """Foxglove's layout tree for `panels` stacked top to bottom, each the same height."""
    if len(panels) == 1:
        return panels[0]
    return {"direction": "column", "first": panels[0], "second": _column(panels[1:]),
            "splitPercentage": round(100 / len(panels), 1)}


def _rule_path(name: str, **style) -> dict:
    """A Plot panel's series of one rule's value over time, from its topic (`topics.RULE_TOPICS`), labelled with
    its name unless `style` says otherwise."""
    return {"value": f"{topics.RULE_TOPICS[name]}.data", "enabled": True, "timestampMethod": "receiveTime",
            "label": name, **style}


def foxglove_layout(target: tuple[float, float] = (0.0, 0.0), profile: Profile | None = None,
                    rule: str = DEFAULT_RULE, reactive: bool = False) -> dict:
    """A Foxglove layout for an attack bag: a top-down 3D panel over `target` (map frame) with each
    layer on its own topic in its own colour (the bag's marker colours), the attacked `rule` over time, every
    rule of the rulebook over time (in Foxglove's palette) and the JSON summary; under a stack's interface
    `profile`, a raw-messages panel for each layer the bag also holds in the stack's own types (Foxglove draws
    no Autoware or vision_msgs objects in 3D, but reads their schemas from the MCAP file); under `reactive`
    traffic, the recording the agents left too.
    config/foxglove_layout.json is this layout over the origin, for our own types and the collision rule."""
    markers = {topics.GROUND_TRUTH: "ground_truth", **({topics.RECORDED_AGENTS: "recorded"} if reactive else {}),
               topics.PERCEPTION: "perception", topics.TRACKING: "tracking", topics.LANES: "lanes"}
    layers = {topic: {"visible": True, "color": _hex(cdr.COLORS[kind]), "showOutlines": True}
              for topic, kind in markers.items()}
    layers[topics.ODOMETRY] = {"visible": True, "type": "arrow", "arrowScale": [4.0, 0.8, 0.8], "color": _hex(EGO_COLOR),
                               "showCovariance": False}
    layers[topics.PLAN] = {"visible": True, "type": "line", "lineWidth": 0.4,
                           "gradient": [_hex(PLAN_COLOR), _hex((*PLAN_COLOR[:3], 0.3))]}
    layers[topics.ROUTE] = {"visible": True, "type": "line", "lineWidth": 0.15, "gradient": ["#80808080", "#80808080"]}
    three_d, plot, rulebook, summary = "3D!attack", "Plot!attacked_rule", "Plot!rulebook", "RawMessages!summary"
    attacked = rule_class(rule)
    own = {f"RawMessages!{name}": (name, layer) for name, layer in
           (stack_layers(profile).items() if profile is not None else ())}
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
                "foxglovePanelTitle": "attack: truth white (reactive traffic: its recording grey), perceived green, "
                                      "tracks blue, ego red, plan orange",
            },
            plot: {
                "foxglovePanelTitle": f"{rule} ({attacked.unit}), the attacked rule: {attacked.meaning}; < 0 a violation",
                "paths": [_rule_path(rule, label=f"{rule} ({attacked.unit})", color=_hex(EGO_COLOR))],
                "showLegend": True,
                "isSynced": True,
            },
            rulebook: {
                "foxglovePanelTitle": "every rule of the rulebook (each in its own unit), < 0 a violation",
                "paths": [_rule_path(name) for name in topics.RULE_TOPICS],
                "showLegend": True,
                "isSynced": True,
            },
            summary: {"topicPath": f"{topics.SUMMARY}.data", "foxglovePanelTitle": "attack summary (report.json)"},
            **{panel: {"topicPath": layer.topic, "foxglovePanelTitle": f"{name} as the stack reads it: {layer.msgtype}"}
               for panel, (name, layer) in own.items()},
        },
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1.0},
        "layout": {"direction": "row", "first": three_d, "splitPercentage": 65,
                   "second": _column([plot, rulebook, summary, *own])},
    }


def write_foxglove_layout(path: Path, layout: dict) -> None:
    path.write_text(json.dumps(layout, indent=2) + "\n")


def write_errors(path: Path, outcome: AttackOutcome) -> None:
    errors = outcome.attack.errors
    agents = outcome.scenario.agents
    slot_ids = agents.ids[agents.valid.argmax(axis=0), np.arange(agents.shape[1])]
    np.savez_compressed(
        path, **errors.arrays(), agent_ids=slot_ids, stamps_ns=outcome.scenario.stamps_ns,  # type: ignore[arg-type]
    )


def load_errors(path: Path) -> PerceptionErrors:
    """The error tensor of a results folder; one ResultsError line if the file is not one."""
    try:
        with np.load(path) as data:
            arrays = {name: data[name] for name in data.files if name not in ("agent_ids", "stamps_ns")}
    except (OSError, ValueError, KeyError, EOFError) as exc:
        raise ResultsError(f"{path}: not an error tensor (npz with dx, dy, dyaw, fn): {exc}") from None
    try:
        return PerceptionErrors.from_arrays(arrays)
    except ValueError as exc:
        raise ResultsError(f"{path}: {exc}") from None


def read_attack(results: Path) -> tuple[AttackParams, Path, PerceptionErrors]:
    """A results folder's params, bag (found as the attack found it; checked against the report's
    bag_sha256) and error tensor, from any working directory; one line for whatever is wrong."""
    report_path, errors_path = results / REPORT_JSON, results / ERRORS
    for needed in (report_path, errors_path):
        if not needed.is_file():
            raise ResultsError(f"{needed}: missing; this needs the results folder of an attack that collided")
    try:
        report = json.loads(report_path.read_text())
        flat = dict(report["params"])
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as exc:
        raise ResultsError(f"{report_path}: not the report of an attack (no 'params'): {exc}") from None
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
    from advperc_ros.results import plots

    with staged_folder(Path(output)) as staging:
        staging.mkdir()
        report = build_report(outcome, bag_path)
        text = json.dumps(report, indent=2, sort_keys=True)
        (staging / REPORT_JSON).write_text(text + "\n")
        (staging / REPORT_MD).write_text(report_markdown(report))
        write_search_log(staging / SEARCH_LOG, outcome.log)
        plots.metric_vs_rollouts(staging / METRIC_PLOT, outcome.log, outcome.params.objective,
                                 method_class(outcome.params.search.method).phases)
        if outcome.best is not None:
            write_errors(staging / ERRORS, outcome)
            write_attack_bag(staging / BAG_DIR, outcome, text)
            watched = tuple(outcome.attack_rollout.ego[outcome.violation_frame, :2])
            write_foxglove_layout(staging / FOXGLOVE_LAYOUT, foxglove_layout(
                watched, load_profile(outcome.params.graph.interface), outcome.attacked_rule,
                outcome.attack_rollout.agents is not None))
            plots.birds_eye_view(staging / BEV_PLOT, outcome)
            plots.attack_animation(staging / ANIMATION, outcome)
    return report
