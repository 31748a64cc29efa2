"""Rules as a campaign axis: a cell per rule, named by its rule unless it is the default collision (so a
campaign from before rules were an axis keeps its cells, and adding a rule runs only the new rule's), the
rule in every summary row and in the JUnit test cases, the same table on the serial and process executors,
and a bad `rules` refused before any work."""

import csv
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import yaml
from test_campaign import _records, run
from test_cli import write_params

from advperc_ros.campaign import spec
from advperc_ros.campaign.summary import CellStatus, verdict
from advperc_ros.cli import main

# phantom braking takes a ghost (a false positive), which only the error kinds beyond the paper's make
ALL_ERRORS = {"errors.kinds": "all"}
COLLISION, PHANTOM = "idm_lane_following-nds_t-0-idm", "idm_lane_following-nds_t-0-idm-phantom_braking"


def write_campaign(path: Path, repo: Path, output: Path, **fields) -> Path:
    document = {"name": "rules", "output": str(output), "scenarios": [str(repo / "config" / "idm_lane_following.yaml")],
                "overrides": ALL_ERRORS, "executor": "serial", **fields}
    path.write_text(yaml.safe_dump({key: value for key, value in document.items() if value is not None}))
    return path


@pytest.fixture(scope="module")
def grown(repo, tmp_path_factory) -> dict:
    """A campaign run without `rules` (its params file's own rule, the collision), then with `rules`
    [collision, phantom_braking] added to the same file and run again into the same output."""
    base = tmp_path_factory.mktemp("rules")
    output = base / "serial"
    campaign = write_campaign(base / "rules.yaml", repo, output)
    assert main(["campaign", str(campaign), "--quiet"]) == 0
    before = json.loads((output / "summary.json").read_text())["cells"]
    kept = (output / COLLISION / "report.json").stat().st_mtime_ns
    write_campaign(campaign, repo, output, rules=["collision", "phantom_braking"])
    assert main(["campaign", str(campaign), "--quiet"]) == 0
    return {"campaign": campaign, "output": output, "before": before, "kept": kept}


def test_adding_a_rule_to_a_finished_campaign_runs_only_the_new_rules_cells(grown, capsys):
    assert [row["cell"] for row in grown["before"]] == [COLLISION]  # the name a campaign had before rules
    assert (grown["output"] / COLLISION / "report.json").stat().st_mtime_ns == grown["kept"]
    assert [row["cell"] for row in _records(grown["output"])] == [COLLISION, PHANTOM]
    summary = run(grown["campaign"], capsys=capsys)
    assert (summary["ran"], summary["finished_before"]) == (0, 2)


def test_each_cell_attacks_its_rule_and_its_row_names_it(grown):
    output = grown["output"]
    rows = {row["cell"]: row for row in _records(output)}
    reports = {cell: json.loads((output / cell / "report.json").read_text()) for cell in rows}
    assert [(rows[cell]["rule"], reports[cell]["rule"]) for cell in (COLLISION, PHANTOM)] == [
        ("collision", "collision"), ("phantom_braking", "phantom_braking")]
    # the ghost makes the ego brake hard for nothing without hitting anyone: the cell's finding all the same
    broken = reports[PHANTOM]["rules"]
    assert broken["phantom_braking"]["violated"] and not broken["collision"]["violated"]
    assert rows[PHANTOM]["collision"] is True and rows[PHANTOM]["outcome"] == "failure"
    assert rows[PHANTOM]["nds_t"] == reports[PHANTOM]["nds_t"] >= 0.9
    assert rows[COLLISION]["verdict"] == f"fails: collision attack with NDS-t {reports[COLLISION]['nds_t']:.4f}"
    assert rows[PHANTOM]["verdict"] == f"fails: phantom_braking attack with NDS-t {reports[PHANTOM]['nds_t']:.4f}"
    with (output / "summary.csv").open() as table:
        assert [(row["cell"], row["rule"]) for row in csv.DictReader(table)] == [
            (COLLISION, "collision"), (PHANTOM, "phantom_braking")]
    lines = (output / "summary.md").read_text().splitlines()
    assert "2 cells: 2 break their rule, 2 failing their threshold (JUnit failures), 0 errors, 0 not finished." in lines
    assert lines[4].startswith("| scenario | planner | objective | rule | seed |")
    assert [line.split(" | ")[3] for line in lines[6:8]] == ["collision", "phantom_braking"]


def test_the_junit_test_cases_name_their_rule(grown):
    (suite,) = ET.parse(grown["output"] / "junit.xml").getroot().findall("testsuite")
    cases = {case.get("name"): case for case in suite.findall("testcase")}
    assert list(cases) == [COLLISION, PHANTOM]
    for name, rule in ((COLLISION, "collision"), (PHANTOM, "phantom_braking")):
        (prop,) = cases[name].findall("properties/property")
        assert (prop.get("name"), prop.get("value")) == ("rule", rule)
        assert cases[name].get("classname") == "rules.idm_lane_following"
    assert cases[PHANTOM].find("failure").get("message").startswith("fails: phantom_braking attack with NDS-t ")
    assert "planner that breaks rule phantom_braking with NDS-t " in cases[PHANTOM].find("failure").text
    assert "planner that collides with NDS-t " in cases[COLLISION].find("failure").text


def test_the_process_executor_gives_the_same_table(grown, capsys):
    output = grown["output"].parent / "process"
    summary = run(grown["campaign"], "--executor", "process", "--workers", "2", "--output", str(output), capsys=capsys)
    assert summary["ran"] == 2
    assert (output / "summary.md").read_text() == (grown["output"] / "summary.md").read_text()
    assert _records(output) == _records(grown["output"])


def test_a_rule_found_unbroken_passes_naming_the_rule(grown):
    """...without the closest approach in metres, which a search for another rule may have taken below 0."""
    cell = next(cell for cell in spec.plan(spec.load_campaign(grown["campaign"])) if cell.name == PHANTOM)
    judged = verdict(CellStatus(cell, {"collision": False, "closest_approach": {"min_signed_distance": -0.04}}), {})
    assert (judged.outcome, judged.text) == ("pass", "passes: no phantom_braking violation found")


@pytest.mark.parametrize("fields, field, says", [
    ({"rules": "phantom_braking"}, "rules", "must be a non-empty list"),
    ({"rules": []}, "rules", "must be a non-empty list"),
    ({"rules": ["brake_checking"]}, "rules", "has 'brake_checking': each one of collision, at_fault_collision"),
    ({"rules": ["collision", "collision"]}, "rules", "lists a value twice"),
    ({"overrides": {"rule.name": "phantom_braking"}}, "overrides", "sets 'rule.name', which the cells vary"),
    ({"rules": ["phantom_braking"], "overrides": {"rule.at_fault_only": True}}, "rules",
     "parameter 'rule.at_fault_only' is true, but it is of the collision rule and rule.name is phantom_braking"),
    ({"rules": ["collision", "phantom_braking"], "scenarios": "at-fault params"}, "rules",
     "parameter 'rule.at_fault_only' is true, but it is of the collision rule and rule.name is phantom_braking"),
    ({"rules": ["collision"], "scenarios": None, "replay": "."}, "rules", "does not apply to a replay campaign"),
])
def test_a_bad_rules_field_is_refused_before_any_work(repo, tmp_path, capsys, fields, field, says):
    if fields.get("scenarios") == "at-fault params":
        fields = {**fields, "scenarios": [str(write_params(tmp_path / "p.yaml", repo, **{"rule.at_fault_only": True}))]}
    output = tmp_path / "out"
    campaign = write_campaign(tmp_path / "bad.yaml", repo, output, **fields)  # scenarios None: none (a replay)
    capsys.readouterr()
    assert main(["campaign", str(campaign), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith(f"advperc: error: {campaign}: field '{field}' ") and says in err, err
    assert not output.exists()
