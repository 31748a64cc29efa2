"""A campaign's summary, one row per cell in the campaign's order: summary.csv and summary.json (every
figure), summary.md and summary.html (Table 1's layout; the page shows each cell's pictures) and
junit.xml (a test case per cell, failing when an attack reaches its objective's threshold).

A cell's finding is an attack that breaks its rule, which report.json's `collision` says whatever the
rule (a collision for the default rule); the rows keep that name, and say the rule in a column of its
own, and the JUnit test cases in a property and in their failure message.

The tables hold nothing that depends on how or when the cells ran (wall times and the workers' peak
memory are in the CSV, JSON and JUnit only), so every executor writes the same summary.md for the same campaign and seeds.
"""

import csv
import io
import json
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from html import escape
from pathlib import Path
from urllib.parse import quote

from advperc_ros.campaign.spec import ATTACK, REPLAY, SUMMARY_JSON, Campaign, Cell
from advperc_ros.campaign.transfer import (
    baseline_markdown,
    baseline_rows,
    transfer_html,
    transfer_markdown,
    transfer_rows,
)
from advperc_ros.core.rules.verdict import CONTACT_RULES
from advperc_ros.replay import BEV_PLOT as REPLAY_BEV
from advperc_ros.replay import REPLAY_MD
from advperc_ros.results.folder import ANIMATION, BEV_PLOT, METRIC_PLOT, REPORT_MD

SUMMARY_CSV, SUMMARY_MD, SUMMARY_HTML, JUNIT_XML = ("summary.csv", "summary.md", "summary.html", "junit.xml")
FAILURE, PASS, ERROR, PENDING = "failure", "pass", "error", "pending"  # a cell's outcome (JUnit's words)
ATTACK_FIELDS = ("heuristic_fn", "heuristic_tp", "heuristic_nds", "heuristic_nds_t", "fn", "tp", "mpe", "maoe", "nds",
                 "nds_t", "pem_ll", "rollouts", "min_signed_distance", "closest_approach")
REPLAY_FIELDS = ("attack", "attack_planner", "attack_metric", "attack_min_signed_distance", "min_signed_distance",
                 "ground_truth_min_signed_distance", "fn", "tp", "nds", "nds_t", "pem_ll")
NAMES = {"nds": "NDS", "nds_t": "NDS-t", "pem_ll": "PEM LL"}
TEXT_COLUMNS = ("scenario", "planner", "objective", "rule", "attack", "attacked", "replayed on")  # left-aligned in the page


@dataclass(frozen=True)
class CellStatus:
    """What the summary knows of one cell (finished, failed, running or pending), read from its folder
    or its worker, so that a summary can be written at any moment of a campaign."""

    cell: Cell
    report: dict | None = None  # report.json (replay.json) of a finished cell
    error: str | None = None  # why the cell failed in this run (a line, or a bug's traceback)
    running: bool = False
    peak_rss_mib: float | None = None  # the worker's peak resident memory while it ran the cell


@dataclass(frozen=True)
class Verdict:
    """A cell's line in the summary: failure, pass, error or pending, with the metric and threshold
    that decided it, so a reader sees why, not just what."""

    outcome: str  # FAILURE, PASS, ERROR or PENDING
    text: str
    metric: float | None = None
    threshold: float | None = None


def verdict(status: CellStatus, thresholds: dict[str, float]) -> Verdict:
    """A found attack (one that breaks the cell's rule) fails when its metric reaches the objective's
    threshold (any attack found fails an objective without one); a replay fails the same way when the
    attack still breaks its rule (its verdict: still collides, still violates phantom_braking)."""
    if status.error is not None:
        return Verdict(ERROR, status.error.strip().splitlines()[-1])
    report = status.report
    if report is None:
        return Verdict(PENDING, "running" if status.running else "pending")
    replayed = status.cell.attack is not None
    objective = status.cell.objective
    threshold = thresholds.get(objective)
    if replayed and report["inconclusive"]:
        return Verdict(ERROR, report["verdict"], threshold=threshold)
    rule = status.cell.rule
    if not report["collision"] and not replayed and rule not in CONTACT_RULES:
        # no closest approach in metres: this rule's search may well have collided, which it does not count
        return Verdict(PASS, f"passes: no {rule} violation found", threshold=threshold)
    if not report["collision"]:
        distance = report["min_signed_distance"] if replayed else report["closest_approach"]["min_signed_distance"]
        return Verdict(PASS, f"passes: {report['verdict'] if replayed else 'no collision'}, closest approach "
                             f"{distance:.2f} m", threshold=threshold)
    metric = report["metric"] if replayed else report[objective]
    found = f"{report['verdict'] if replayed else f'{rule} attack'} with {NAMES[objective]} {metric:.4f}"
    if threshold is None:
        return Verdict(FAILURE, f"fails: {found}", metric)
    if metric >= threshold:
        return Verdict(FAILURE, f"fails: {found} >= {threshold:g}", metric, threshold)
    return Verdict(PASS, f"passes: {found} < {threshold:g}", metric, threshold)


def record(status: CellStatus, thresholds: dict[str, float]) -> dict:
    """A cell's row of summary.csv and summary.json."""
    cell, report, judged = status.cell, status.report or {}, verdict(status, thresholds)
    row = {"cell": cell.name, "scenario": cell.scenario, "planner": cell.planner, "objective": cell.objective,
           "seed": cell.seed, "rule": cell.rule, "outcome": judged.outcome, "verdict": judged.text,
           "collision": report.get("collision"), "metric": judged.metric, "threshold": judged.threshold}
    if cell.attack is None:
        heuristic = report.get("heuristic") or {}
        row.update({f"heuristic_{key}": heuristic.get(key) for key in ("fn", "tp", "nds", "nds_t")})
        row.update({key: report.get(key) for key in ATTACK_FIELDS if not key.startswith("heuristic_")})
        row["closest_approach"] = (report.get("closest_approach") or {}).get("min_signed_distance")
    else:
        row.update({key: report.get(key) for key in REPLAY_FIELDS}, attack=str(cell.attack))
    row.update(config_hash=report.get("config_hash"), wall_time_s=report.get("wall_time_s"),
               worker_peak_rss_mib=status.peak_rss_mib, error=status.error)
    return row


def _f(value, digits: int = 3) -> str:
    return "" if value is None else f"{value:.{digits}f}"


def _scores(record: dict, objective: str, names: tuple[str, ...]) -> list[str]:
    """The metric columns, the objective's in bold (Table 1's way)."""
    return [f"**{_f(record[name])}**" if name == objective else _f(record[name]) for name in names]


def _columns(campaign: Campaign, records: list[dict]) -> tuple[list[str], tuple[str, ...]]:
    """(headers, metric names) of the table: Table 1's columns; PEM LL only when a cell maximises it."""
    metrics = ("nds", "nds_t", *(("pem_ll",) if any(r["objective"] == "pem_ll" for r in records) else ()))
    names = [NAMES[m] for m in metrics]
    if campaign.replay is not None:
        return ["attack", "scenario", "objective", "attacked", "replayed on", "min signed distance (m): attack / replay",
                *names, "verdict"], metrics
    return ["scenario", "planner", "objective", "rule", "seed", "heuristic FN/TP, NDS / NDS-t", "attack FN/TP", "MPE (m)",
            "MAOE (rad)", *names, "rollouts", "verdict"], metrics


def _cells(campaign: Campaign, row: dict, metrics: tuple[str, ...]) -> list[str]:
    """A row of the table as text (Markdown emphasis included)."""
    scores = _scores(row, row["objective"], metrics) if row["collision"] or campaign.replay else [""] * len(metrics)
    if campaign.replay is not None:
        distances = f"{_f(row['attack_min_signed_distance'])} / {_f(row['min_signed_distance'])}"
        return [Path(row["attack"]).name, row["scenario"], row["objective"], row["attack_planner"] or "",
                row["planner"], distances, *scores, row["verdict"]]
    heuristic = (f"{row['heuristic_fn']}/{row['heuristic_tp']}, {_f(row['heuristic_nds'])} / {_f(row['heuristic_nds_t'])}"
                 if row["heuristic_fn"] is not None else "")
    found = row["collision"]
    return [row["scenario"], row["planner"], row["objective"], row["rule"], str(row["seed"]), heuristic,
            f"{row['fn']}/{row['tp']}" if found else "", _f(row["mpe"], 2) if found else "",
            _f(row["maoe"], 2) if found else "", *scores, str(row["rollouts"] or ""), row["verdict"]]


def _counts(records: list[dict]) -> str:
    outcomes = [r["outcome"] for r in records]
    found = sum(1 for r in records if r["collision"])
    broken = "collide" if all(r["rule"] in CONTACT_RULES for r in records) else "break their rule"
    return (f"{len(records)} cells: {found} {broken}, {outcomes.count(FAILURE)} failing their threshold (JUnit failures), "
            f"{outcomes.count(ERROR)} errors, {outcomes.count(PENDING)} not finished")


def _thresholds(campaign: Campaign) -> str:
    given = ", ".join(f"{NAMES[k]} {v:g}" for k, v in sorted(campaign.thresholds.items())) or "none"
    return f"thresholds: {given} (an attack fails its test case when its metric reaches the threshold of its objective; " \
           f"any attack found fails an objective without one)"


def markdown(campaign: Campaign, records: list[dict], transfer: list[dict], baseline: list[dict]) -> str:
    headers, metrics = _columns(campaign, records)
    lines = [f"# Campaign {campaign.name}", "", _counts(records) + ".", "",
             "| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(_cells(campaign, r, metrics)).replace("\n", " ") + " |" for r in records]
    lines += ["", f"- {_thresholds(campaign)}"]
    lines += [f"- {r['cell']}: {r['verdict']}" for r in records if r["outcome"] == ERROR]
    lines += transfer_markdown(transfer) + baseline_markdown(baseline)
    return "\n".join(lines) + "\n"


STYLE = """
body { font-family: sans-serif; margin: 1.5em; color: #222; }
table { border-collapse: collapse; font-size: 14px; }
th, td { border: 1px solid #bbb; padding: 4px 8px; text-align: right; vertical-align: middle; }
th { background: #eee; } td.text { text-align: left; }
tr.failure td.verdict { background: #f8d0d0; } tr.pass td.verdict { background: #d4efd4; }
tr.error td.verdict { background: #f3e2b3; } tr.pending td.verdict { background: #e4e4e4; }
td.breaks, td.found, td.still, td.newly { background: #f8d0d0; } td.holds, td.fixed, td.clear { background: #d4efd4; }
h2 { margin-top: 1.5em; }
img { display: block; max-width: 640px; }
"""


def _picture(folder: str, names: tuple[str, ...], base: Path) -> str:
    """The first of `names` the cell folder holds, shown and linked to full size."""
    for name in names:
        if (base / folder / name).is_file():
            src = f"{quote(folder)}/{quote(name)}"
            return f'<a href="{src}"><img src="{src}" alt="{escape(folder)}: {escape(name)}"></a>'
    return ""


def html_page(campaign: Campaign, records: list[dict], output: Path, transfer: list[dict], baseline: list[dict]) -> str:
    headers, metrics = _columns(campaign, records)
    rows = []
    for record in records:
        texts = _cells(campaign, record, metrics)
        cells = []
        for header, text in zip(headers, texts):
            bold = text.startswith("**")
            body = escape(text.strip("*"))
            kind = "verdict text" if header == "verdict" else "text" if header in TEXT_COLUMNS else ""
            cells.append(f'<td class="{kind}">' + (f"<b>{body}</b>" if bold else body) + "</td>")
        folder = record["cell"]
        report = REPLAY_MD if campaign.replay is not None else REPORT_MD
        links = [f'<a href="{quote(folder)}/{quote(name)}">{name}</a>' for name in (report, ANIMATION)
                 if (output / folder / name).is_file()]
        picture = _picture(folder, (REPLAY_BEV, BEV_PLOT, METRIC_PLOT), output)
        cells.append(f'<td class="text"><b>{escape(folder)}</b> {" ".join(links)}{picture}</td>')
        rows.append(f'<tr class="{record["outcome"]}">' + "".join(cells) + "</tr>")
    header = "".join(f"<th>{escape(h)}</th>" for h in [*headers, "cell and picture"])
    return "\n".join([
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        f"<title>advperc campaign {escape(campaign.name)}</title><style>{STYLE}</style></head><body>",
        f"<h1>Campaign {escape(campaign.name)}</h1>", f"<p>{escape(_counts(records))}.</p>",
        f"<p>{escape(_thresholds(campaign))}.</p>",
        f"<table><thead><tr>{header}</tr></thead><tbody>", *rows, "</tbody></table>", *transfer_html(transfer, baseline),
        "</body></html>", ""])


def junit(campaign: Campaign, statuses: list[CellStatus], records: list[dict]) -> str:
    """One test suite, one test case per cell (classname <campaign>.<scenario>), its rule a property and,
    when not the default, the end of its name (the cell's): a dashboard shows which rule failed."""
    outcomes = [r["outcome"] for r in records]
    total = sum(r["wall_time_s"] or 0.0 for r in records)
    counts = {"tests": str(len(records)), "failures": str(outcomes.count(FAILURE)), "errors": str(outcomes.count(ERROR)),
              "skipped": str(outcomes.count(PENDING)), "time": f"{total:.3f}"}
    suites = ET.Element("testsuites", {"name": f"advperc campaign {campaign.name}", **counts})
    suite = ET.SubElement(suites, "testsuite", {"name": campaign.name, **counts})
    for status, record in zip(statuses, records):
        case = ET.SubElement(suite, "testcase", classname=f"{campaign.name}.{record['scenario']}", name=record["cell"],
                             time=f"{record['wall_time_s'] or 0.0:.3f}")
        ET.SubElement(ET.SubElement(case, "properties"), "property", name="rule", value=record["rule"])
        if record["outcome"] == FAILURE:
            collides = campaign.replay is not None or record["rule"] in CONTACT_RULES
            broken = "collides" if collides else f"breaks rule {record['rule']}"
            ET.SubElement(case, "failure", message=record["verdict"], type="AdversarialPerceptionAttack").text = (
                f"{campaign.output / record['cell']}: an attack on the {record['planner']} planner that {broken} with "
                f"{NAMES[record['objective']]} {record['metric']:.4f}; open the folder's report and bag")
        elif record["outcome"] == ERROR:
            ET.SubElement(case, "error", message=record["verdict"]).text = status.error or record["verdict"]
        elif record["outcome"] == PENDING:
            ET.SubElement(case, "skipped", message="not finished")
        ET.SubElement(case, "system-out").text = json.dumps({k: v for k, v in record.items() if v is not None})
    ET.indent(suites)
    return ET.tostring(suites, encoding="unicode", xml_declaration=True) + "\n"


def _csv(records: list[dict]) -> str:
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=list(records[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(records)
    return out.getvalue()


def _write(path: Path, text: str) -> None:
    """Replace `path` at once: a reader (or a kill) never sees half a summary."""
    staging = path.with_name(f".{path.name}.partial")
    staging.write_text(text)
    os.replace(staging, path)


def _baseline_before(campaign: Campaign) -> dict[str, dict]:
    """The baseline run's summary rows by cell name (checked readable when the campaign was planned)."""
    if campaign.baseline is None:
        return {}
    return {row["cell"]: row for row in json.loads((campaign.baseline / SUMMARY_JSON).read_text())["cells"]}


def write_summary(campaign: Campaign, output: Path, statuses: list[CellStatus]) -> list[dict]:
    """All five summary files; returns the records of the campaign's own cells (its attacks, or a replay
    campaign's replays): the transfer and baseline replays are summed up in sections of their own."""
    own = [status for status in statuses if status.cell.role in (ATTACK, REPLAY)]
    records = [record(status, dict(campaign.thresholds)) for status in own]
    transfer, baseline = transfer_rows(statuses), baseline_rows(statuses, _baseline_before(campaign))
    document = {"campaign": campaign.name, "source": str(campaign.source.resolve()),
                "thresholds": dict(campaign.thresholds), "cells": records, "transfer": transfer, "baseline": baseline}
    _write(output / SUMMARY_JSON, json.dumps(document, indent=2) + "\n")
    _write(output / SUMMARY_CSV, _csv(records))
    _write(output / SUMMARY_MD, markdown(campaign, records, transfer, baseline))
    _write(output / SUMMARY_HTML, html_page(campaign, records, output, transfer, baseline))
    _write(output / JUNIT_XML, junit(campaign, own, records))
    return records
