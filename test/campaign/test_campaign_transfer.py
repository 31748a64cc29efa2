"""Attacks that travel: a campaign of several planners replays every attack it finds on the other planners
(the transfer matrix), and a campaign with a `baseline` replays the last version's attacks on this one.

The planners: IDM as the params file has it (`idm`), IDM keeping 3 s to its lead instead of 1.5 s
(`cautious`), and, as a next version that no hidden lead can crash, IDM at 4 m/s (slower than the lead:
hiding the lead only lets it drive away)."""

import json
import shutil
from pathlib import Path

import pytest
import yaml
from test_campaign import SHORT, run

from advperc_ros.cli import main

IDM, CAUTIOUS, SLOW = {"name": "idm"}, {"name": "cautious", "planner_params": {"headway": 3.0}}, {
    "name": "idm", "planner_params": {"target_speed": 4.0}}
CELLS = [f"idm_lane_following-{objective}-0-{planner}" for objective in ("nds", "nds_t") for planner in ("idm", "cautious")]


def write(path: Path, repo: Path, planners: list[dict], **fields) -> Path:
    document = {"name": "transfer", "output": str(path.parent / path.stem),
                "scenarios": [str(repo / "config" / "idm_lane_following.yaml")], "objectives": ["nds", "nds_t"],
                "seeds": [0], "planners": planners, "overrides": SHORT, "executor": "serial", **fields}
    path.write_text(yaml.safe_dump(document))
    return path


def summary(output: Path) -> dict:
    return json.loads((output / "summary.json").read_text())


@pytest.fixture(scope="module")
def two_planners(repo, tmp_path_factory) -> Path:
    """The output of a campaign of idm and cautious: read only."""
    campaign = write(tmp_path_factory.mktemp("transfer") / "two.yaml", repo, [IDM, CAUTIOUS])
    assert main(["campaign", str(campaign), "--quiet"]) == 0
    return campaign.parent / "two"


def test_every_attack_found_is_replayed_on_every_other_planner(two_planners):
    """A row per attack found, its own planner `found` at the attack's margin, every other planner the
    verdict and min signed distance of that replay's replay.json, with the other planner's cell's params."""
    document = summary(two_planners)
    assert [row["cell"] for row in document["cells"]] == CELLS  # the replays are no rows of the attack table
    rows = {row["attack"]: row for row in document["transfer"]}
    assert sorted(rows) == sorted(row["cell"] for row in document["cells"] if row["collision"])
    for name, row in rows.items():
        found_on = row["found_on"]
        other = "cautious" if found_on == "idm" else "idm"
        own = json.loads((two_planners / name / "report.json").read_text())
        assert row["on"][found_on] == {"cell": name, "outcome": "found", "margin": own["min_signed_distance"]}
        replayed = json.loads((two_planners / f"{name}-on-{other}" / "replay.json").read_text())
        sibling = json.loads((two_planners / name.replace(f"-{found_on}", f"-{other}") / "report.json").read_text())
        assert replayed["config_hash"] == sibling["config_hash"] and replayed["planner"] == "idm"
        assert replayed["attack"] == str(two_planners.resolve() / name)
        assert row["on"][other] == {"cell": f"{name}-on-{other}", "outcome": "breaks" if replayed["collision"] else "holds",
                                    "margin": replayed["min_signed_distance"]}
        assert (row["on"][other]["margin"] < 0) == replayed["collision"]
    # the nds_t attack on idm displaces the lead, which a planner keeping 3 s to it survives; the rest travel
    assert rows["idm_lane_following-nds_t-0-idm"]["on"]["cautious"]["outcome"] == "holds"
    assert rows["idm_lane_following-nds-0-idm"]["on"]["cautious"]["outcome"] == "breaks"
    table = (two_planners / "summary.md").read_text()
    assert "| found on / replayed on | idm | cautious |" in table
    assert "| idm | 2 found | 1 of 2 break |" in table and "| cautious | 2 of 2 break | 2 found |" in table
    page = (two_planners / "summary.html").read_text()
    assert "<h2>Transfer</h2>" in page and "1 of 2 break" in page


def test_a_resumed_campaign_runs_only_the_replays_not_finished(two_planners, repo, tmp_path, capsys):
    output = tmp_path / "two"
    shutil.copytree(two_planners, output)
    campaign = write(tmp_path / "two.yaml", repo, [IDM, CAUTIOUS], output=str(output))
    document = json.loads((output / "summary.json").read_text())
    document["source"] = str(campaign.resolve())  # the copy's own campaign file
    (output / "summary.json").write_text(json.dumps(document))
    shutil.rmtree(output / "idm_lane_following-nds-0-idm-on-cautious")
    assert run(campaign, capsys=capsys)["ran"] == 1
    assert summary(output)["transfer"] == summary(two_planners)["transfer"]
    assert (output / "summary.md").read_text() == (two_planners / "summary.md").read_text()


def test_the_process_pool_gives_the_serial_transfer_matrix(two_planners, repo, tmp_path, capsys):
    campaign = write(tmp_path / "pool.yaml", repo, [IDM, CAUTIOUS], executor="process", workers=2)
    assert run(campaign, capsys=capsys)["ran"] == 8  # four attacks, all colliding, each replayed once
    assert summary(tmp_path / "pool")["transfer"] == summary(two_planners)["transfer"]
    assert (tmp_path / "pool" / "summary.md").read_text() == (two_planners / "summary.md").read_text()


def test_one_planner_has_nothing_to_transfer(repo, tmp_path, capsys):
    campaign = write(tmp_path / "one.yaml", repo, [IDM], objectives=["nds"])
    assert run(campaign, capsys=capsys)["ran"] == 1
    assert summary(tmp_path / "one")["transfer"] == [] and "## Transfer" not in (tmp_path / "one" / "summary.md").read_text()


def test_a_next_version_against_the_baseline_says_what_it_fixed_and_what_it_broke(two_planners, repo, tmp_path, capsys):
    """idm at 4 m/s fixes both attacks found on idm (they no longer collide, and its own search finds none),
    cautious is unchanged (still broken); back from the slow version to the first, idm is newly broken."""
    slow = write(tmp_path / "slow.yaml", repo, [SLOW, CAUTIOUS], baseline=str(two_planners))
    run(slow, capsys=capsys)
    rows = {row["cell"]: row for row in summary(tmp_path / "slow")["baseline"]}
    assert list(rows) == CELLS
    for cell in CELLS:
        replay = json.loads((tmp_path / "slow" / f"{cell}-baseline" / "replay.json").read_text())
        assert replay["attack"] == str(two_planners / cell)
        assert rows[cell]["replayed"]["margin"] == replay["min_signed_distance"]
        assert rows[cell]["found_before"] is True
    assert [rows[cell]["change"] for cell in CELLS] == ["fixed", "still broken", "fixed", "still broken"]
    assert "4 cells: 2 fixed, 2 still broken." in (tmp_path / "slow" / "summary.md").read_text()
    back = write(tmp_path / "back.yaml", repo, [IDM, CAUTIOUS], baseline=str(tmp_path / "slow"))
    run(back, capsys=capsys)
    changes = {row["cell"]: row["change"] for row in summary(tmp_path / "back")["baseline"]}
    assert changes == dict(zip(CELLS, ["newly broken", "still broken", "newly broken", "still broken"]))
    assert not (tmp_path / "back" / f"{CELLS[0]}-baseline").exists()  # the slow version found nothing to replay


def test_a_replay_on_a_planner_that_cannot_be_attacked_there_is_not_applicable():
    """A replay that failed on a planner whose own cell of the scenario failed too (its ground truth collides)
    has nothing to compare: `n/a`, not counted; one that failed alone stays an error."""
    from advperc_ros.campaign.spec import ATTACK, TRANSFER, Cell
    from advperc_ros.campaign.summary import CellStatus
    from advperc_ros.campaign.transfer import transfer_counts, transfer_rows

    def cell(name, planner, role=ATTACK, origin=None):
        return Cell(name, "s", "nds_t", 0, planner, {"rule.name": "collision"}, None, None, role, origin)

    found = {"collision": True, "min_signed_distance": -0.1, "rules": {"collision": {"value": -0.1}}}
    statuses = [CellStatus(cell("s-a", "a"), found), CellStatus(cell("s-b", "b"), error="collides unattacked"),
                CellStatus(cell("s-c", "c"), {"collision": False}),
                CellStatus(cell("s-a-on-b", "b", TRANSFER, "s-a"), error="collides unattacked"),
                CellStatus(cell("s-a-on-c", "c", TRANSFER, "s-a"), error="a bug")]
    [row] = transfer_rows(statuses)
    assert {planner: entry["outcome"] for planner, entry in row["on"].items()} == {"a": "found", "b": "n/a", "c": "error"}
    assert transfer_counts([row], ["a", "b", "c"])["a"] == {"a": (1, 1), "b": (0, 0), "c": (0, 0)}
