"""Why a search found no collision: the diagnosis of a null result, from the search's own log.

A search that finds nothing still says something: which agents were tried, how close the ego came
with each hidden, whether hiding every vehicle at once could matter at all, and how near the
approach phase brought it. The report (`advperc_ros.results.report`) writes this as its `message` and
its `closest_approach` fields.
"""

import math
import re
from collections import Counter
from collections.abc import Callable

from advperc_ros.core.rollout import RolloutResult
from advperc_ros.core.search.approach import Approach
from advperc_ros.core.search.problem import LogRow


def listed_ids(ids: list[int], shown: int = 10) -> str:
    """Agent ids as a sentence shows them: the first `shown`, then how many in all."""
    text = ", ".join(str(i) for i in ids[:shown])
    return text + (f", ... ({len(ids)} in all)" if len(ids) > shown else "")


def why_no_collision(log: list[LogRow], blind: RolloutResult | None = None, approach: Approach | None = None,
                     distance: Callable[[float], float] = float, rule: str | None = None) -> dict:
    """Why a search found nothing, from its log: the agents whose whole track was dropped (the heuristic
    refines only a drop that collides) and how close the ego came, hidden agent or not; from the
    joint drops' `blind` rollout (every vehicle hidden), whether any drop could matter; and how close
    the `approach` phase (cars shown displaced) brought the ego at its fault. `distance`: how a
    distance is to be written (the report rounds them, `advperc_ros.results.report.rounded`); `rule`: the
    attacked rule when not the collision rule, whose violation is what was not found (the margins are then its r)."""
    truth = next(row for row in log if row.phase == "ground_truth")  # the first rollout, always conclusive
    drops = [row for row in log if row.phase == "heuristic_drop"]
    conclusive = [row for row in drops if not row.inconclusive and math.isfinite(row.min_signed_distance)]
    inconclusive = [row for row in drops if row.inconclusive]
    found, broke = ("no collision found", "made the ego collide") if rule is None else (
        f"no violation of rule {rule} found", f"made the ego break {rule}")
    if not drops:
        text = f"{found}: no agent to attack, the scenario has none"
    else:
        text = (f"{found}: no agent is influential (dropping any one of the {len(drops)} agents "
                f"({listed_ids([r.agent for r in drops])}) for the whole scenario never {broke}), so the "
                f"heuristic had no failure to narrow and the search none to improve")
    if inconclusive:
        text += (f"; the drops of agents {listed_ids([r.agent for r in inconclusive])} were inconclusive "
                 f"({inconclusive[0].inconclusive})")
    if rule is None:
        nearest = min(conclusive, key=lambda row: row.min_signed_distance, default=truth)
        if nearest.min_signed_distance < truth.min_signed_distance:
            text += (f"; closest approach {nearest.min_signed_distance:.2f} m, with agent {nearest.agent} dropped "
                     f"(rollout {nearest.rollout}; perfect perception {truth.min_signed_distance:.2f} m)")
        else:
            nearest = truth
            text += (f"; {'no single drop brought the ego closer than perfect perception does: ' if conclusive else ''}"
                     f"closest approach {truth.min_signed_distance:.2f} m")
    else:  # the attacked rule's r, which every rollout's log row holds: how near a violation each drop came
        nearest = min(conclusive, key=_rule_value, default=truth)
        if _rule_value(nearest) < _rule_value(truth):
            text += (f"; nearest a violation r = {_rule_value(nearest):.2f}, with agent {nearest.agent} dropped "
                     f"(rollout {nearest.rollout}; perfect perception r = {_rule_value(truth):.2f})")
        else:
            nearest = truth
            nothing_nearer = "no single drop brought the ego nearer a violation than perfect perception does: "
            text += f"; {nothing_nearer if conclusive else ''}r = {_rule_value(truth):.2f}"
    blind_report = None
    if blind is not None:
        text += "; " + _blind_clause(blind, rule)
        blind_report = {"collided": blind.collided, "inconclusive": blind.inconclusive,
                        "min_signed_distance": distance(blind.min_signed_distance),
                        "margin": distance(blind.margin)}
    approach_report = None
    if approach is not None:
        text += "; " + _approach_clause(approach, rule)
        approach_report = {"rollouts": approach.rollouts,
                           "start_margin": distance(approach.start.rollout.margin),
                           "closest_margin": distance(approach.closest.rollout.margin)}
    return {
        "message": text,
        "blind": blind_report,
        "approach": approach_report,
        "agents_tried": [row.agent for row in drops],
        "closest_approach": {
            "min_signed_distance": distance(nearest.min_signed_distance),
            "agent": nearest.agent if nearest.agent >= 0 else None,
            "rollout": nearest.rollout,
        },
        "closest_approach_by_agent": {
            str(row.agent): distance(row.min_signed_distance) for row in conclusive
        },
        "ground_truth_min_signed_distance": distance(truth.min_signed_distance),
    }


def _rule_value(row: LogRow) -> float:
    """The attacked rule's r of a logged rollout (a search attacking a rule beyond the collision rule logs it)."""
    return math.inf if row.rule_value is None else row.rule_value


def _blind_clause(blind: RolloutResult, rule: str | None) -> str:
    """What hiding every vehicle does, which tells whether missed detections can matter at all: an ego
    that stays clear of the recorded traffic even blind to it is not put in its way by hiding some. (A
    blind rollout that collides is an attack: the joint drops narrow it.)"""
    if blind.inconclusive is not None:
        return f"with every vehicle hidden at once the rollout was inconclusive ({blind.inconclusive})"
    if rule is not None:
        return f"even with every vehicle hidden at once the ego does not break {rule} (r = {blind.margin:.2f})"
    at_fault = (f", {blind.margin:.2f} m where a contact would be its fault"
                if blind.margin != blind.min_signed_distance else "")
    return (f"even with every vehicle hidden at once the ego collides with none at its fault (closest approach "
            f"{blind.min_signed_distance:.2f} m{at_fault}): unseen, the recorded traffic still does not come into its way")


def _approach_clause(approach: Approach, rule: str | None) -> str:
    """How near showing the cars nearest the ego wrongly brought it to a collision at its fault (or to
    breaking the attacked rule)."""
    if rule is not None:
        return (f"showing the cars nearest the ego displaced or hidden for a while ({approach.rollouts} rollouts of "
                f"the approach phase) brought {rule}'s r from {approach.start.rollout.margin:.2f} to "
                f"{approach.closest.rollout.margin:.2f}")
    return (f"showing the cars nearest the ego displaced or hidden for a while ({approach.rollouts} rollouts of "
            f"the approach phase) "
            f"brought its margin to a collision at its fault from {approach.start.rollout.margin:.2f} m to "
            f"{approach.closest.rollout.margin:.2f} m")


INCONCLUSIVE_SHARE = 0.5  # above it, a search that found nothing has not shown that nothing is there


def inconclusive_search(log: list[LogRow]) -> str | None:
    """Why a search without a collision cannot say "no collision found": more than half its rollouts
    were inconclusive (a node dead or silent, another graph on the same domain superseding ours, a
    plug-in raising). The text names how many and the most frequent cause; None when the search's
    null result stands (or it found a collision, which an inconclusive rollout cannot fake)."""
    if any(row.collided and not row.inconclusive for row in log):
        return None
    failed = [row.inconclusive for row in log if row.inconclusive]
    if len(failed) <= INCONCLUSIVE_SHARE * len(log):
        return None
    causes = Counter(re.sub(r"\d+", "N", reason) for reason in failed)
    cause, count = causes.most_common(1)[0]
    example = next(reason for reason in failed if re.sub(r"\d+", "N", reason) == cause)
    return (f"{len(failed)} of {len(log)} rollouts were inconclusive, so the search cannot say that no collision "
            f"exists; the most frequent cause ({count} rollouts): {example}")
