"""The report of an attack: report.json's fields and report.md's text, built from its outcome.

What the report holds is fixed here; `advperc_ros.results.folder` writes it into the results folder with
the bag, the search log and the plots, and `advperc_ros.replay` reuses its scores and rounding.
"""

import math
import platform
from functools import partial
from importlib import metadata
from pathlib import Path

from advperc_ros import __version__
from advperc_ros.configs import error_kinds
from advperc_ros.core.rules.base import RuleValue
from advperc_ros.core.rules.verdict import CONTACT_RULES, DEFAULT_RULE
from advperc_ros.core.search.diagnosis import listed_ids, why_no_collision
from advperc_ros.core.search.problem import Evaluation, kind_costs
from advperc_ros.core.traffic import REACTIVE, REPLAYED, deviations
from advperc_ros.results.outcome import AttackOutcome
from advperc_ros.ros import bag as bags

WALL_CLOCK_FIELDS = ("wall_time_s",)
TRAJECTORY_FIELDS = ("min_signed_distance", "pem_ll", "metric")
"""Report floats that depend continuously on the ego trajectory. The graph backend's trajectory
differs from the embedded one in the last bits (messages carry yaw as a quaternion and velocity as
an arrow; docs/graph.md), so these are rounded to REPORT_DIGITS significant digits and both
backends write the same report. Every other float is the same to the bit in both, but under reactive
traffic, where the true agents themselves follow the ego's trajectory (core.traffic), and so every
score of the perception against them: there every float is rounded."""
REPORT_DIGITS = 7
LIBRARIES = ("numpy", "scipy", "filterpy", "casadi", "rosbags", "mcap-ros2-support", "matplotlib")


def _finite_or_none(value: float) -> float | None:
    return None if value is None or (isinstance(value, float) and math.isnan(value)) else value


def rounded(name: str, value, reactive: bool = False):
    """`value` as report.json holds it: trajectory-derived floats to REPORT_DIGITS (see above), every float
    under reactive traffic (`reactive`)."""
    if (reactive or name in TRAJECTORY_FIELDS) and isinstance(value, float) and math.isfinite(value):
        return float(f"{value:.{REPORT_DIGITS}g}")
    return value


def report_scores(evaluation: Evaluation, reactive: bool = False) -> dict:
    """An evaluation's scores as report.json holds them (NaN as null, rounded as `rounded`)."""
    return {k: rounded(k, _finite_or_none(v), reactive) for k, v in evaluation.scores.as_dict().items()}


def traffic_entries(outcome: AttackOutcome) -> dict:
    """report.json's `traffic` (`reactive` or `replayed`) and, under reactive traffic, `deviated_agents`: the
    agents of the attack's rollout that left their recording (id, frames off it, how far, how hard they braked)."""
    if outcome.rollout_config.traffic is None:
        return {"traffic": REPLAYED}
    rollout = outcome.recorded
    simulated = None if rollout is None else rollout.agents
    deviated = None
    if rollout is not None and simulated is not None:
        deviated = [{"agent": d.agent, "frames": d.frames, "max_distance": rounded("", d.max_distance, True),
                     "hardest_braking": rounded("", d.hardest_braking, True)}
                    for d in deviations(outcome.scenario.agents, simulated.frames(rollout.num_frames),
                                        outcome.scenario.dt)]
    return {"traffic": REACTIVE, "deviated_agents": deviated}


def rule_entry(value: RuleValue) -> dict:
    """One rule's verdict on a rollout as report.json holds it: its value (null where nothing can bring it near a
    violation, as a rule with no agent to meet), whether it is violated and the first frame that violates it.
    Rounded as the trajectory's floats, so both backends write the same report."""
    finite = value.value if math.isfinite(value.value) else None
    return {"value": None if finite is None else float(f"{finite:.{REPORT_DIGITS}g}"), "violated": value.violated,
            "frame": value.first_violation}


def rulebook(outcome: AttackOutcome) -> dict:
    """report.json's `rules` (every registered rule on the attack's rollout, null without an attack) and
    `ground_truth_rules` (on perfect perception's rollout, null if the search ended before it)."""
    judged = {"rules": outcome.attack_rules, "ground_truth_rules": outcome.ground_truth_rules}
    return {key: None if values is None else {name: rule_entry(value) for name, value in values.items()}
            for key, values in judged.items()}


def versions() -> dict[str, str]:
    """This package's, Python's and the numeric libraries' versions: what a report was computed with."""
    out = {"advperc_ros": __version__, "python": platform.python_version()}
    for name in LIBRARIES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def build_report(outcome: AttackOutcome, bag_path: Path) -> dict:
    """report.json's fields: the attack found (Table 1's row) or why none was, and what it ran with."""
    params = outcome.params
    best = outcome.best
    reactive = outcome.rollout_config.traffic is not None
    report: dict = {
        "scenario": outcome.scenario.name,
        "bag": params.bag,
        "bag_sha256": bags.digest(bag_path),
        "planner": params.planner,
        "objective": params.objective,
        "attacked_layer": params.attacked_layer,
        "error_kinds": {"enabled": list(error_kinds(params))},
        "seed": params.seed,
        "rule": params.rule.name,  # the rule attacked: `collision` says whether an attack broke it
        **traffic_entries(outcome),
        "collision": best is not None,
        "min_signed_distance": None,
        "collision_frame": None,
        "collision_agent": None,
    }
    if outcome.planner_node is not None:
        report["planner_node"] = outcome.planner_node
    if outcome.planner_version is not None:
        report["planner_version"] = outcome.planner_version
    if outcome.tracker_node is not None:  # a team's tracker made the tracks: ours and its parameters did not
        report["tracker_node"] = outcome.tracker_node
    if best is not None:
        rollout = outcome.attack_rollout
        frame, slot = rollout.closest_approach()
        report.update(
            reproduced=outcome.reproduced,
            min_signed_distance=rounded("min_signed_distance", rollout.min_signed_distance),
            collision_frame=frame,
            collision_agent=int(outcome.scenario.agents.ids[frame, slot]),
            **report_scores(best, reactive),
        )
        costs = kind_costs(outcome.scenario, best, params.objective, error_kinds(params))
        report["error_kinds"].update(used=list(costs), cost={kind: rounded(kind, _finite_or_none(cost), reactive)
                                                             for kind, cost in costs.items()})
    else:
        report.update(why_no_collision(outcome.log, outcome.joint.blind.rollout if outcome.joint else None,
                                       outcome.approach, partial(rounded, "min_signed_distance"),
                                       None if params.rule.name in CONTACT_RULES else params.rule.name))
    if outcome.heuristic_best is not None:
        report["heuristic"] = {"metric": rounded("metric", outcome.heuristic_best.metric),
                               **report_scores(outcome.heuristic_best, reactive)}
    report.update(rulebook(outcome))
    # no single drop collided: the agents the joint drops' failure mode hides together ([]: none found)
    report["joint_agents"] = list(outcome.joint.agents) if outcome.joint is not None else None
    report.update(
        rollouts=len(outcome.log),
        inconclusive_rollouts=sum(1 for row in outcome.log if row.inconclusive),
        wall_time_s=outcome.wall_time_s,
        config_hash=params.config_hash(planner_node=outcome.planner_node, tracker_node=outcome.tracker_node,
                                       planner_version=outcome.planner_version),
        params=params.canonical(),
        versions=versions(),
    )
    return report


def _traffic_line(report: dict) -> list[str]:
    """Under reactive traffic, the line that says so and who reacted (nothing for replayed traffic, the paper's)."""
    if report["traffic"] != REACTIVE:
        return []
    deviated = report.get("deviated_agents") or []
    who = ", ".join(f"agent {d['agent']} ({d['max_distance']:.2f} m behind its recording, braking at most "
                    f"{d['hardest_braking']:.2f} m/s^2)" for d in deviated) or "no agent left its recording"
    return [f"Traffic reacts to the ego (IDM along the recorded paths, docs/traffic.md): {who}.", ""]


def _fmt(value, digits: int = 2) -> str:
    return "N/A" if value is None else f"{value:.{digits}f}"


def _planner_label(report: dict) -> str:
    node = report.get("planner_node")
    version = f" version {report['planner_version']}" if "planner_version" in report else ""
    label = report["planner"] if node is None else f"{report['planner']} ({node or 'node name unknown'}{version})"
    tracker = report.get("tracker_node")
    return label if tracker is None else f"{label} on the tracks of external tracker {tracker or '(node name unknown)'}"


def report_markdown(report: dict) -> str:
    """report.md: the report as the paper's Table 1 row, or why no collision was found."""
    layer = ", errors on the tracked objects" if report["attacked_layer"] == "tracks" else ""
    rule = "" if report["rule"] == DEFAULT_RULE else f", rule {report['rule']}"
    title = (f"# Attack on {report['scenario']} ({_planner_label(report)} planner, objective {report['objective']}"
             f"{rule}{layer})")
    lines = [title, ""] + _traffic_line(report) + (_table(report) if report["collision"] else _no_collision(report)) + \
        _rules_table(report) + [
        "",
        f"- seed {report['seed']}, config hash {report['config_hash']}, {report['rollouts']} rollouts, "
        f"wall time {report['wall_time_s']:.1f} s",
        "",
    ]
    return "\n".join(lines)


NOT_REPRODUCED = ("- **not reproduced**: rolled out again after the search, this attack did not give the verdict and "
                  "minimum signed distance the search saw, so the planner (or a node of the graph) depends on more "
                  "than its reset and its inputs; the attack and its bag may not replay")


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
    return [
        *lines,
        "",
        _verdict_line(report),
        *([] if report["reproduced"] else [NOT_REPRODUCED]),
        *([f"- no single agent's drop collided: agents {listed_ids(joint)} dropped jointly"] if joint else []),
        _kinds_line(report),
        "- TP/FN: ground-truth cars within 50 m matched / not matched at 4 m; MPE and MAOE over TPs",
    ]


def _rules_table(report: dict) -> list[str]:
    """Every rule of the rulebook on the attack's rollout and on the ground truth's: r (< 0 a violation, from
    its first frame on)."""
    truth, attack = report.get("ground_truth_rules"), report.get("rules")
    if truth is None:
        return []

    def cell(entry: dict | None) -> str:
        if entry is None:
            return ""
        value = "no violation possible" if entry["value"] is None else f"{entry['value']:.3f}"
        return f"**{value} (violated from frame {entry['frame']})**" if entry["violated"] else value

    lines = ["", "| rule | attack | ground truth |", "|---|---|---|"]
    return lines + [f"| {name} | {cell(attack[name] if attack else None)} | {cell(entry)} |"
                     for name, entry in truth.items()]


def _verdict_line(report: dict) -> str:
    """What the attack broke: the collision (the paper's rule, or its at-fault variant), or the attacked rule from its
    first violating frame."""
    if report["rule"] in CONTACT_RULES:
        return (f"- collision with agent {report['collision_agent']} at frame {report['collision_frame']}, "
                f"min signed distance {report['min_signed_distance']:.3f} m")
    broken = report["rules"][report["rule"]]
    return (f"- rule {report['rule']} violated from frame {broken['frame']}, r = {broken['value']:.3f}; closest approach "
            f"to agent {report['collision_agent']} at frame {report['collision_frame']}, "
            f"{report['min_signed_distance']:.3f} m")


def _kinds_line(report: dict) -> str:
    """Which error kinds the attack uses of those enabled, and what each costs the objective."""
    kinds = report["error_kinds"]
    costs = ", ".join(f"{kind} {_fmt(cost, 4)}" for kind, cost in kinds["cost"].items())
    return (f"- error kinds used: {', '.join(kinds['used']) or 'none'} (of {', '.join(kinds['enabled'])}); "
            f"{report['objective']} each costs: {costs or 'nothing'}")


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
