"""Attacks that travel: the transfer matrix of a campaign of several planners, and the comparison of a
planner version with the last one (a campaign's `baseline`).

A planner team asks of an attack whether it breaks only the planner it was found on or their next
version too. The campaign answers with replays (`spec.transfer_cells`, `spec._baseline_cells`); this
module reads their reports into rows: per attack, on every planner, whether it breaks the rule and by
what margin (the rule's value, below 0 when broken: for a collision the min signed distance in m), and
per cell, what the baseline's attack and this version's search say together.
"""

from collections.abc import Sequence
from dataclasses import dataclass
from html import escape
from typing import TYPE_CHECKING

from advperc_ros.campaign.spec import ATTACK, BASELINE, TRANSFER
from advperc_ros.core.rules.registry import rule_class

if TYPE_CHECKING:  # summary.py imports this module for its tables
    from advperc_ros.campaign.summary import CellStatus

FOUND, BREAKS, HOLDS, INCONCLUSIVE, FAILED, PENDING = "found", "breaks", "holds", "inconclusive", "error", "pending"
UNATTACKED = "n/a"  # a replay on a planner whose own cell of the scenario failed (its ground truth collides)
# a cell against the baseline: its attack replayed on this version, and this version's own search
STILL_BROKEN, FIXED, FIXED_OTHER, NEWLY_BROKEN, CLEAR, UNKNOWN = (
    "still broken", "fixed", "fixed, another attack found", "newly broken", "clear", "pending")


@dataclass(frozen=True)
class TransferEntry:
    """One attack on one planner: found there by the search, or replayed there from another planner's cell."""

    cell: str  # the attack's cell, or the replay's
    outcome: str  # FOUND, BREAKS, HOLDS, INCONCLUSIVE, FAILED or PENDING
    margin: float | None  # the rule's value on that planner's rollout (< 0: broken); None until known

    def text(self, unit: str) -> str:
        """The outcome and margin as a table shows them (a unit in words is left to the rule's page)."""
        if self.margin is None:
            return self.outcome
        return f"{self.outcome} {self.margin:.2f}" + ("" if " " in unit else f" {unit}")


def attack_margin(report: dict, rule: str) -> float:
    """The attacked rule's value on the attack's rollout (report.json's table of every rule)."""
    entry = (report.get("rules") or {}).get(rule)
    return float(entry["value"]) if entry else float(report["min_signed_distance"])


def replay_margin(report: dict) -> float:
    """The replayed rule's value (replay.json: `rule_value`, or for the collision rule the min signed distance)."""
    value = report.get("rule_value")
    return float(report["min_signed_distance"] if value is None else value)


def replay_entry(status: "CellStatus") -> TransferEntry:
    """A replay cell's outcome: whether the attack still breaks the rule on the planner it was replayed on."""
    name, report = status.cell.name, status.report
    if status.error is not None:
        return TransferEntry(name, FAILED, None)
    if report is None:
        return TransferEntry(name, PENDING, None)
    if report["inconclusive"]:
        return TransferEntry(name, INCONCLUSIVE, None)
    return TransferEntry(name, BREAKS if report["collision"] else HOLDS, replay_margin(report))


def _planners(statuses: Sequence["CellStatus"]) -> list[str]:
    """The campaign's planners in its own order."""
    return list(dict.fromkeys(s.cell.planner for s in statuses if s.cell.role == ATTACK))


def transfer_rows(statuses: Sequence["CellStatus"]) -> list[dict]:
    """summary.json's `transfer`: a row per attack found (in table order), its entry on every planner of the
    campaign (the planner it was found on: FOUND); empty unless the campaign attacks several planners."""
    planners = _planners(statuses)
    if len(planners) < 2:
        return []
    replays = {(s.cell.origin, s.cell.planner): s for s in statuses if s.cell.role == TRANSFER}
    failed = {(s.cell.key, s.cell.planner) for s in statuses if s.cell.role == ATTACK and s.error is not None}
    rows = []
    for status in statuses:
        cell, report = status.cell, status.report
        if cell.role != ATTACK or not report or not report.get("collision"):
            continue
        entries = {}
        for planner in planners:
            if planner == cell.planner:
                entries[planner] = TransferEntry(cell.name, FOUND, attack_margin(report, cell.rule))
            elif (cell.name, planner) in replays:
                entry = replay_entry(replays[cell.name, planner])
                # that planner's own cell failed as the replay did: nothing to compare on it, not a fault of the replay
                entries[planner] = TransferEntry(entry.cell, UNATTACKED, None) if (
                    entry.outcome == FAILED and (cell.key, planner) in failed) else entry
            else:  # the attack is finished; its replays are not planned yet
                entries[planner] = TransferEntry(f"{cell.name}-on-{planner}", PENDING, None)
        rows.append({"attack": cell.name, "scenario": cell.scenario, "objective": cell.objective, "seed": cell.seed,
                     "rule": cell.rule, "unit": rule_class(cell.rule).unit, "found_on": cell.planner,
                     "on": {planner: vars(entry) for planner, entry in entries.items()}})
    return rows


def transfer_counts(rows: list[dict], planners: list[str]) -> dict[str, dict[str, tuple[int, int]]]:
    """Per planner found on, per planner replayed on: (attacks that break it, attacks replayed and
    conclusive); on the diagonal (attacks found, attacks found)."""
    counts: dict[str, dict[str, tuple[int, int]]] = {p: dict.fromkeys(planners, (0, 0)) for p in planners}
    for row in rows:
        for planner, entry in row["on"].items():
            broken, judged = counts[row["found_on"]][planner]
            if entry["outcome"] in (FOUND, BREAKS, HOLDS):
                counts[row["found_on"]][planner] = (broken + (entry["outcome"] != HOLDS), judged + 1)
    return counts


def _matrix(rows: list[dict]) -> tuple[list[str], list[list[str]], list[str], list[list[str]]]:
    """(headers, rows) of the counts table and of the per-attack table, as text."""
    planners = list(rows[0]["on"])
    counts = transfer_counts(rows, planners)
    count_rows = [[found_on] + [f"{b} found" if found_on == q else f"{b} of {n} break" for q, (b, n) in
                                counts[found_on].items()] for found_on in planners]
    attack_rows = [[row["attack"], row["rule"]] + [
        TransferEntry(**row["on"][planner]).text(row["unit"])
        for planner in planners] for row in rows]
    return ["found on / replayed on", *planners], count_rows, ["attack", "rule", *planners], attack_rows


TRANSFER_NOTE = ("Each attack found on one planner (rows), replayed unchanged on every other planner of the campaign "
                 "(columns), with that planner's cell's params: whether it still breaks the rule, and the margin, the "
                 "rule's value on that rollout (below 0: broken; for a collision the min signed distance in m).")


def transfer_markdown(rows: list[dict]) -> list[str]:
    """summary.md's transfer section (no lines when there is nothing to transfer)."""
    if not rows:
        return []
    count_headers, counts, headers, attacks = _matrix(rows)
    lines = ["", "## Transfer", "", TRANSFER_NOTE, ""]
    for head, body in ((count_headers, counts), (headers, attacks)):
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        lines += ["| " + " | ".join(row) + " |" for row in body] + [""]
    return lines[:-1]


def _html_table(headers: list[str], rows: list[list[str]]) -> str:
    head = "".join(f"<th>{escape(h)}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f'<td class="text {escape(t.split(" ")[0])}">{escape(t)}</td>' for t in row)
                   + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def transfer_html(rows: list[dict], baseline: list[dict]) -> list[str]:
    """summary.html's transfer and baseline sections."""
    parts = []
    if rows:
        count_headers, counts, headers, attacks = _matrix(rows)
        parts += ["<h2>Transfer</h2>", f"<p>{escape(TRANSFER_NOTE)}</p>", _html_table(count_headers, counts),
                  "<p></p>", _html_table(headers, attacks)]
    if baseline:
        parts += ["<h2>Against the baseline</h2>", f"<p>{escape(BASELINE_NOTE)}</p>",
                  _html_table(BASELINE_HEADERS, [_baseline_texts(row) for row in baseline])]
    return parts


def _change(before: bool | None, replayed: str | None, now: bool | None) -> str:
    """What a cell's two versions say together: the baseline found an attack (`before`), which on this
    version `replayed` (BREAKS, HOLDS...), and this version's search found one (`now`)."""
    if before is None or now is None or (before and replayed not in (BREAKS, HOLDS)):
        return UNKNOWN
    if before:
        return STILL_BROKEN if replayed == BREAKS else FIXED_OTHER if now else FIXED
    return NEWLY_BROKEN if now else CLEAR


def baseline_rows(statuses: Sequence["CellStatus"], before: dict[str, dict]) -> list[dict]:
    """summary.json's `baseline`: a row per attack cell of this campaign that the baseline ran (`before`, its
    summary rows by cell name), with what it found then, its attack replayed now and what was found now."""
    replays = {s.cell.origin: s for s in statuses if s.cell.role == BASELINE}
    rows = []
    for status in statuses:
        cell = status.cell
        if cell.role != ATTACK or cell.name not in before:
            continue
        then = before[cell.name].get("collision")
        replayed = replay_entry(replays[cell.name]) if cell.name in replays else None
        now = None if status.report is None else bool(status.report.get("collision"))
        rows.append({"cell": cell.name, "rule": cell.rule, "unit": rule_class(cell.rule).unit, "found_before": then,
                     "replayed": None if replayed is None else vars(replayed), "found_now": now,
                     "change": _change(then, replayed.outcome if replayed else None, now)})
    return rows


BASELINE_NOTE = ("Each cell against the same cell of the baseline run (the last version): the attack the baseline found "
                 "replayed on this version, and what this version's own search found. 'fixed': the old attack no longer "
                 "breaks the rule and the search finds none; 'newly broken': the search finds an attack where the "
                 "baseline found none.")
BASELINE_HEADERS = ["cell", "rule", "found before", "its attack now", "found now", "change"]


def _yes(value: bool | None) -> str:
    return "" if value is None else "yes" if value else "no"


def _baseline_texts(row: dict) -> list[str]:
    replayed = "" if row["replayed"] is None else TransferEntry(**row["replayed"]).text(row["unit"])
    return [row["cell"], row["rule"], _yes(row["found_before"]), replayed, _yes(row["found_now"]), row["change"]]


def baseline_markdown(rows: list[dict]) -> list[str]:
    """summary.md's baseline section (no lines without a baseline)."""
    if not rows:
        return []
    changes = [row["change"] for row in rows]
    counted = ", ".join(f"{changes.count(c)} {c}" for c in (FIXED, FIXED_OTHER, STILL_BROKEN, NEWLY_BROKEN, CLEAR, UNKNOWN)
                        if changes.count(c))
    lines = ["", "## Against the baseline", "", BASELINE_NOTE, "", f"{len(rows)} cells: {counted}.", "",
             "| " + " | ".join(BASELINE_HEADERS) + " |", "|" + "---|" * len(BASELINE_HEADERS)]
    return lines + ["| " + " | ".join(_baseline_texts(row)) + " |" for row in rows]

