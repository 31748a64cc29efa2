"""Replay a found attack against another planner or configuration: does its error tensor still make
the ego collide (or break the rule the attack broke)? A regression check after a fix, or a transfer
test from one planner to another.

The errors are the attack's own (`attack_errors.npz` of its results folder), replayed unchanged on
the same scenario: the bag the replay's params name must hash as the attack's did (`bag_sha256`).
The ground truth is rolled out first, as an attack does: a configuration that collides with perfect
perception has nothing to say about the attack. A replay folder, like a results folder, is written
into a hidden staging folder and renamed into place.
"""

import json
import time
from dataclasses import dataclass
from pathlib import Path

from advperc_ros.backends.registry import open_rollouts
from advperc_ros.configs import core_configs
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.rules.verdict import attacked_rule
from advperc_ros.core.scenario import Scenario
from advperc_ros.core.search.problem import (
    AttackProblem,
    Evaluation,
    Phase,
)
from advperc_ros.core.staging import staged_folder
from advperc_ros.exceptions import BagError, GroundTruthFails, OutputError, ParamsError, ResultsError
from advperc_ros.params import AttackParams, params_from_values, resolve_bag
from advperc_ros.results.folder import ERRORS, REPORT_JSON, load_errors
from advperc_ros.results.outcome import AttackOutcome
from advperc_ros.results.report import report_scores, rounded, versions
from advperc_ros.ros import bag as bags
from advperc_ros.ros.bag import read_scenario

REPLAY_JSON = "replay.json"
# what a replay reads of the attack's report.json besides its params (older or hand-made reports may lack one)
ATTACK_FIELDS = ("bag_sha256", "config_hash", "min_signed_distance", "planner", "scenario", "seed")
REPLAY_MD = "replay.md"
BEV_PLOT = "bev.png"  # the replayed rollout's last seconds, when it still collides


@dataclass(frozen=True)
class FoundAttack:
    """An attack as its results folder holds it: the report, the error tensor and the params it ran with."""

    folder: Path
    report: dict
    errors: PerceptionErrors
    params: AttackParams


@dataclass(frozen=True)
class Replay:
    """A found attack's errors rolled out again under other params (another planner, seed or
    backend): whether the failure carries over is what a planner engineer asks of a bag first."""

    attack: FoundAttack
    params: AttackParams  # what the errors were replayed against
    scenario: Scenario
    truth_min_signed_distance: float  # of the ground-truth rollout under these params
    evaluation: Evaluation  # the attack's errors rolled out under these params, recorded
    wall_time_s: float

    @property
    def verdict(self) -> str:
        """`still collides` or `no longer collides` under the collision rule; under another rule the attack
        broke, `still violates <rule>` or `no longer violates <rule>`."""
        rollout, rule = self.evaluation.rollout, self.params.rule.name
        if rollout.inconclusive:
            return f"inconclusive ({rollout.inconclusive})"
        if rollout.verdict is not None:
            return f"{'still' if rollout.collided else 'no longer'} violates {rule}"
        return "still collides" if rollout.collided else "no longer collides"


def load_attack(folder: Path) -> FoundAttack:
    """The attack of a results folder; ResultsError when it is not one of an attack that collided."""
    folder = Path(folder)
    report_path, errors_path = folder / REPORT_JSON, folder / ERRORS
    if not report_path.is_file():
        raise ResultsError(f"{report_path}: missing; replay needs the results folder of an attack")
    try:
        report = json.loads(report_path.read_text())
        values = dict(report["params"])  # AttackParams.canonical(): planner_params included
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ResultsError(f"{report_path}: not an attack report: {exc}") from exc
    missing = [field for field in ATTACK_FIELDS if not isinstance(report, dict) or field not in report]
    if missing:
        raise ResultsError(f"{report_path}: field '{missing[0]}' missing: not an attack report of advperc")
    if not report.get("collision") or not errors_path.is_file():
        raise ResultsError(f"{folder}: the search found no collision there, so there is no attack to replay")
    params = params_from_values(values, report_path)
    return FoundAttack(folder, report, load_errors(errors_path), params)


def replay_params(attack: FoundAttack, other: AttackParams | None) -> AttackParams:
    """The params to replay with: `other`'s (its planner, tracker, ego, backend) judged on the attack's
    objective and by the rule it broke, with its thresholds (`rule.*`), or the attack's own when there is
    no other."""
    if other is None:
        return attack.params
    judged = {name: value for name, value in attack.params.flat().items() if name.startswith("rule.")}
    return other.with_values(objective=attack.params.objective, **judged)


def replay(attack: FoundAttack, params: AttackParams, bag_path: Path | None = None) -> Replay:
    """Roll out the ground truth and then the attack's errors under `params`; `bag_path`, as for
    `attack_to_folder`: where the bag they name is, when not where they name it."""
    started = time.perf_counter()
    bag_path = bag_path if bag_path is not None else resolve_bag(params)
    digest = bags.digest(bag_path)
    if digest != attack.report["bag_sha256"]:
        raise ParamsError(f"{params.source or 'params'}: parameter 'bag' names {bag_path}, not the scenario the attack "
                          f"in {attack.folder} was found on (bag_sha256 {digest[:12]}, "
                          f"not {attack.report['bag_sha256'][:12]})")
    scenario = read_scenario(bag_path)
    if attack.errors.shape != scenario.agents.shape:
        raise BagError(f"{attack.folder / ERRORS}: field 'fn' has shape {attack.errors.shape}, the bag {bag_path} has "
                       f"{scenario.agents.shape}")
    configs = core_configs(params)
    rule = attacked_rule(params.rule.name, scenario, configs.rollout, configs.rulebook)
    with open_rollouts(scenario, configs, bag_path) as rollouts:
        problem = AttackProblem(scenario, rollouts.rollout, params.objective, kinds=configs.search.errors.kinds,
                                attacked_rule=rule)
        truth = problem.evaluate(PerceptionErrors.none(*scenario.agents.shape), Phase.GROUND_TRUTH).rollout
        if truth.inconclusive or truth.collided:
            why = truth.inconclusive or (f"min signed distance {truth.min_signed_distance:.3f} m" if rule is None
                                         else f"rule {rule.name} at {truth.verdict:.4g} {rule.rule.unit}")
            raise GroundTruthFails(f"{params.planner}: the ground truth does not pass with perfect perception ({why}); "
                                   f"replaying the attack in {attack.folder} cannot tell anything")
        result = rollouts.rollout(attack.errors, record=True)
        if rule is not None:  # judged as the search judged it, against this configuration's ground truth
            result = rule.judge(result, truth)
    scores = problem.scores(attack.errors, result)
    evaluation = Evaluation(attack.errors, result, scores, getattr(scores, params.objective))
    return Replay(attack, params, scenario, truth.min_signed_distance, evaluation, time.perf_counter() - started)


def replay_report(replayed: Replay) -> dict:
    """replay.json: the attack replayed, the configuration, and whether it still collides."""
    attack, params, rollout = replayed.attack.report, replayed.params, replayed.evaluation.rollout
    frame, slot = rollout.closest_approach()
    return {
        "attack": str(replayed.attack.folder),
        "scenario": replayed.scenario.name,
        "bag": params.bag,
        "bag_sha256": attack["bag_sha256"],
        "objective": params.objective,
        "seed": attack["seed"],
        "attack_planner": attack["planner"],
        "attack_config_hash": attack["config_hash"],
        "attack_min_signed_distance": attack["min_signed_distance"],
        "attack_metric": attack[params.objective],
        "planner": params.planner,
        "rule": params.rule.name,
        "collision": rollout.collided,
        "verdict": replayed.verdict,
        "rule_value": None if rollout.verdict is None else rounded("min_signed_distance", rollout.verdict),
        "inconclusive": rollout.inconclusive,
        "min_signed_distance": rounded("min_signed_distance", rollout.min_signed_distance),
        "closest_frame": frame,
        "closest_agent": int(replayed.scenario.agents.ids[frame, slot]),
        "metric": rounded("metric", replayed.evaluation.metric),
        **report_scores(replayed.evaluation),
        "ground_truth_min_signed_distance": rounded("min_signed_distance", replayed.truth_min_signed_distance),
        "wall_time_s": replayed.wall_time_s,
        "config_hash": params.config_hash(),
        "params": params.canonical(),
        "versions": versions(),
    }


def replay_markdown(report: dict) -> str:
    return "\n".join([
        f"# Replay of {report['attack']} on the {report['planner']} planner: {report['verdict']}",
        "",
        "| | planner | min signed distance (m) | metric |",
        "|---|---|---|---|",
        f"| attack | {report['attack_planner']} | {report['attack_min_signed_distance']:.3f} "
        f"| {report['attack_metric']:.4f} |",
        f"| replay | {report['planner']} | {report['min_signed_distance']:.3f} | {report['metric']:.4f} |",
        "",
        (f"- scenario {report['scenario']}, objective {report['objective']}, seed {report['seed']}; closest approach "
         f"to agent {report['closest_agent']} at frame {report['closest_frame']}; with perfect perception "
         f"{report['ground_truth_min_signed_distance']:.3f} m"),
        f"- config hash {report['config_hash']} (the attack's {report['attack_config_hash']})",
        "",
    ])


def write_replay(output: Path, replayed: Replay) -> dict:
    """The replay folder, written atomically: replay.json, replay.md and, when it still collides,
    bev.png; returns the report."""
    from advperc_ros.results import plots

    output = Path(output)
    if output.exists():
        raise OutputError(f"{output}: output folder exists already; choose another output")
    with staged_folder(output) as staging:
        staging.mkdir()
        report = replay_report(replayed)
        (staging / REPLAY_JSON).write_text(json.dumps(report, indent=2, sort_keys=True) + "\n")
        (staging / REPLAY_MD).write_text(replay_markdown(report))
        if report["collision"]:
            evaluation = replayed.evaluation
            outcome = AttackOutcome(scenario=replayed.scenario, params=replayed.params, heuristic_best=None,
                                    best=evaluation, recorded=evaluation.rollout, log=[],
                                    wall_time_s=replayed.wall_time_s)
            plots.birds_eye_view(staging / BEV_PLOT, outcome)
    return report
