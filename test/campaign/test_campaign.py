"""`advperc campaign`: cells and summary, the same table on every executor, resuming (finished cells are
not run again; a killed cell or campaign restarts cleanly), the JUnit verdicts, replay campaigns, the
HTML page, refusals before any work; and the attack's progress bar, which ends at the rollouts run."""

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from html.parser import HTMLParser
from importlib.util import find_spec
from pathlib import Path

import pytest
import yaml
from test_cli import write_params

from advperc_ros.backends.resumed import checkpoint_folder
from advperc_ros.campaign import spec
from advperc_ros.campaign.execute import CellResult, ProcessExecutor
from advperc_ros.cli import main

# a short search by the paper's method, whose attacks (the lead dropped, or displaced) these tests pin
SHORT = {"search.method": "paper", "search.random.steps": 1, "search.random.proposals": 10,
         "search.heuristic.iterations": 1, "search.refine.iterations": 0}
CELLS = ("idm_lane_following-nds-0-idm", "idm_lane_following-nds_t-0-idm")


def write_campaign(path: Path, repo: Path, output: Path, **fields) -> Path:
    document = {"name": "small", "output": str(output), "scenarios": [str(repo / "config" / "idm_lane_following.yaml")],
                "objectives": ["nds", "nds_t"], "seeds": [0], "overrides": SHORT, "executor": "serial", **fields}
    path.write_text(yaml.safe_dump(document))
    return path


def run(campaign: Path, *flags: str, capsys) -> dict:
    """The campaign's one-line JSON summary; it must end with exit code 0."""
    capsys.readouterr()
    assert main(["campaign", str(campaign), "--quiet", *flags]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.fixture(scope="module")
def campaign(repo, tmp_path_factory) -> Path:
    base = tmp_path_factory.mktemp("campaign")
    return write_campaign(base / "small.yaml", repo, base / "serial")


@pytest.fixture(scope="module")
def serial(campaign) -> Path:
    """The output of the campaign run serially: read only (tests that change it work on a copy)."""
    assert main(["campaign", str(campaign), "--quiet"]) == 0
    return campaign.parent / "serial"


def _records(output: Path) -> list[dict]:
    return [{k: v for k, v in row.items() if k not in ("wall_time_s", "worker_peak_rss_mib")}
            for row in json.loads((output / "summary.json").read_text())["cells"]]


def _mtimes(output: Path) -> dict[str, float]:
    return {cell: (output / cell / "report.json").stat().st_mtime_ns for cell in CELLS}


def test_every_cell_has_its_folder_and_its_row(serial):
    for cell in CELLS:
        assert (serial / cell / "report.json").is_file() and (serial / cell / "bev.png").is_file()
    for name in ("summary.csv", "summary.json", "summary.md", "summary.html", "junit.xml"):
        assert (serial / name).is_file(), name
    records = _records(serial)
    assert [row["cell"] for row in records] == list(CELLS)
    assert [row["objective"] for row in records] == ["nds", "nds_t"]
    for row in records:
        report = json.loads((serial / row["cell"] / "report.json").read_text())
        assert (row["collision"], row["nds"], row["nds_t"], row["rollouts"]) == (
            report["collision"], report["nds"], report["nds_t"], report["rollouts"])
    table = (serial / "summary.md").read_text()
    assert "| scenario | planner | objective | rule | seed | heuristic FN/TP, NDS / NDS-t | attack FN/TP |" in table
    assert not list(serial.glob(".*partial"))


def need_ray() -> None:
    """Skip where the ray extra is missing, but fail in CI's Ray venv (ADVPERC_REQUIRE_RAY=1). Ray is not
    imported here: a campaign sets Ray's environment before it imports it."""
    if find_spec("ray") is None:
        if os.environ.get("ADVPERC_REQUIRE_RAY") == "1":
            pytest.fail("ray cannot be imported though ADVPERC_REQUIRE_RAY=1")
        pytest.skip("the ray extra is not installed (pip install '.[ray]'; it cannot share an environment with "
                    "commonroad-io, so CI runs this in a venv of its own)")


@pytest.mark.parametrize("executor", ["process", "ray"])
def test_every_executor_gives_the_same_table(serial, campaign, executor, capsys):
    if executor == "ray":
        need_ray()
    output = campaign.parent / executor
    assert run(campaign, "--executor", executor, "--workers", "2", "--output", str(output), capsys=capsys)["ran"] == 2
    assert (output / "summary.md").read_text() == (serial / "summary.md").read_text()
    assert _records(output) == _records(serial)


def _memory(output: Path) -> list[float | None]:
    return [row["worker_peak_rss_mib"] for row in json.loads((output / "summary.json").read_text())["cells"]]


def test_a_finished_campaign_runs_no_cell_again(serial, campaign, capsys):
    """...and its summary keeps the workers' peak memory that the run which ran the cells measured."""
    before, memory = _mtimes(serial), _memory(serial)
    summary = run(campaign, capsys=capsys)
    assert (summary["ran"], summary["finished_before"]) == (0, 2)
    assert _mtimes(serial) == before
    assert _memory(serial) == memory and all(mib > 50 for mib in memory)


def assert_resumes_the_second_cell_only(campaign, output, serial, capsys) -> None:
    """Running the campaign again runs the unfinished cell only, leaves the finished one's folder
    untouched and no staging behind, and ends with the uninterrupted campaign's table."""
    kept = (output / CELLS[0] / "report.json").stat().st_mtime_ns
    summary = run(campaign, "--output", str(output), capsys=capsys)
    assert (summary["ran"], summary["finished_before"]) == (1, 1)
    assert (output / CELLS[0] / "report.json").stat().st_mtime_ns == kept
    assert not list(output.glob(".*partial"))
    assert (output / "summary.md").read_text() == (serial / "summary.md").read_text()


def test_a_killed_cell_restarts_cleanly(serial, campaign, tmp_path, capsys):
    """What a kill leaves: a cell without its folder but with its staging folder, a summary's staging file."""
    output = tmp_path / "resumed"
    shutil.copytree(serial, output)
    shutil.rmtree(output / CELLS[1])
    (output / f".{CELLS[1]}.partial").mkdir()
    (output / f".{CELLS[1]}.partial" / "report.json").write_text("{half")
    (output / ".summary.md.partial").write_text("half")
    assert_resumes_the_second_cell_only(campaign, output, serial, capsys)


def _children(pid: int) -> list[int]:
    children = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            children.append(int(stat.parent.name))
    return children


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc; workers die with the campaign on Linux")
def test_a_campaign_killed_midway_resumes_without_redoing_finished_cells(serial, campaign, repo, tmp_path, capsys):
    output = tmp_path / "killed"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, (str(repo), os.environ.get("PYTHONPATH")))))
    process = subprocess.Popen([sys.executable, "-m", "advperc_ros.cli", "campaign", str(campaign), "--executor", "process",
                                "--workers", "1", "--output", str(output), "--quiet"], cwd=repo, env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while not (output / CELLS[0] / "report.json").is_file():
        assert process.poll() is None and time.monotonic() < deadline, "the first cell never finished"
        time.sleep(0.2)
    workers = _children(process.pid)
    assert workers and not (output / CELLS[1]).exists(), "kill came too late: the second cell had finished"
    process.send_signal(signal.SIGKILL)  # the campaign alone: its workers must not outlive it
    process.wait()
    deadline = time.monotonic() + 30
    while any(_alive(worker) for worker in workers):
        assert time.monotonic() < deadline, "a worker outlived its campaign"
        time.sleep(0.2)
    assert_resumes_the_second_cell_only(campaign, output, serial, capsys)


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc")
def test_a_worker_killed_from_outside_costs_its_cell_one_more_run(serial, campaign, repo, tmp_path):
    output = tmp_path / "worker-killed"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, (str(repo), os.environ.get("PYTHONPATH")))))
    process = subprocess.Popen([sys.executable, "-m", "advperc_ros.cli", "campaign", str(campaign), "--executor", "process",
                                "--workers", "1", "--output", str(output), "--quiet"], cwd=repo, env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    deadline = time.monotonic() + 300
    while not checkpoint_folder(output / CELLS[1]).is_dir():  # the second cell began: the first one has answered
        assert process.poll() is None and time.monotonic() < deadline, "the second cell never began"
        time.sleep(0.05)
    (worker,) = [pid for pid in _children(process.pid)  # running the second cell (not the resource tracker)
                 if b"resource_tracker" not in Path(f"/proc/{pid}/cmdline").read_bytes()]
    os.kill(worker, signal.SIGKILL)
    out, _ = process.communicate(timeout=300)
    assert process.returncode == 0
    assert json.loads(out)["errors"] == 0 and (output / CELLS[1] / "report.json").is_file()
    assert (output / "summary.md").read_text() == (serial / "summary.md").read_text()


def test_a_cell_whose_worker_died_after_its_folder_was_in_place_is_finished(serial, campaign, repo, tmp_path, capsys):
    """A worker killed between its cell's results folder going into place and its answer: the cell is
    finished, not lost; run again, it would meet its own folder and fail on it."""
    output = tmp_path / "answered"
    shutil.copytree(serial, output)
    cell = spec.plan(spec.load_campaign(campaign))[0]
    checkpoint_folder(output / cell.name).mkdir()  # what the kill left: the checkpoint outlives its folder
    pool = ProcessExecutor(output, 1)
    try:
        pool.lost.add(cell.name)  # even a cell lost before
        pool._replace_pool([cell])
        assert pool.next_done() == CellResult(cell.name) and not pool.futures
    finally:
        pool.close()
    again = write_campaign(tmp_path / "again.yaml", repo, output)  # the same campaign, owning the copy
    summary = json.loads((output / "summary.json").read_text())
    (output / "summary.json").write_text(json.dumps({**summary, "source": str(again.resolve())}))
    again = run(again, capsys=capsys)
    assert again["finished_before"] == len(CELLS) and not checkpoint_folder(output / cell.name).exists()


def _junit(output: Path) -> dict[str, ET.Element]:
    """The test cases by name, once the file is checked to be one consistent suite."""
    root = ET.parse(output / "junit.xml").getroot()
    assert root.tag == "testsuites"
    (suite,) = root.findall("testsuite")
    cases = suite.findall("testcase")
    for element in (root, suite):
        assert int(element.get("tests")) == len(cases)
        for kind, tag in (("failures", "failure"), ("errors", "error"), ("skipped", "skipped")):
            assert int(element.get(kind)) == sum(1 for case in cases if case.find(tag) is not None)
    for case in cases:
        assert case.get("classname") == "small.idm_lane_following" and float(case.get("time")) > 0
    return {case.get("name"): case for case in cases}


def test_without_thresholds_every_attack_found_fails(serial):
    cases = _junit(serial)
    assert list(cases) == list(CELLS)
    for case in cases.values():
        assert case.find("failure") is not None and case.find("error") is None


def test_an_attack_fails_its_test_case_when_its_metric_reaches_the_threshold(serial, repo, tmp_path, capsys):
    """Thresholds set in the campaign's own file after it ran: the verdicts change, no cell runs again
    (the output folder is the campaign's own only for its own file)."""
    output = tmp_path / "thresholds"
    campaign = write_campaign(tmp_path / "small.yaml", repo, output)
    assert run(campaign, capsys=capsys)["ran"] == 2
    nds = json.loads((serial / CELLS[0] / "report.json").read_text())["nds"]
    write_campaign(campaign, repo, output, thresholds={"nds": nds, "nds_t": 1.0})
    assert run(campaign, capsys=capsys)["ran"] == 0  # only the verdicts change: no cell runs again
    cases = _junit(output)
    assert cases[CELLS[0]].find("failure") is not None  # reaches nds exactly
    assert cases[CELLS[1]].find("failure") is None  # nds_t below 1.0
    rows = {row["cell"]: row for row in _records(output)}
    assert (rows[CELLS[0]]["outcome"], rows[CELLS[1]]["outcome"]) == ("failure", "pass")


def test_a_replay_campaign_says_which_attacks_still_collide(serial, tmp_path, capsys):
    """On its own planner each attack collides as found; a planner keeping 3 s to its lead rather than
    1.5 s escapes the nds_t attack (which hides the lead by displacing it) but not the nds one (which
    drops it for longer)."""
    planners = [{"name": "idm"}, {"name": "cautious", "planner_params": {"headway": 3.0}}]
    campaign = tmp_path / "replay.yaml"
    campaign.write_text(yaml.safe_dump({"name": "small", "output": str(tmp_path / "replayed"), "replay": str(serial),
                                        "planners": planners, "executor": "serial"}))
    summary = run(campaign, capsys=capsys)
    rows = {row["cell"]: row for row in _records(tmp_path / "replayed")}
    assert list(rows) == [f"{cell}-on-{planner}" for cell in CELLS for planner in ("idm", "cautious")]
    for cell in CELLS:
        own = rows[f"{cell}-on-idm"]
        report = json.loads((serial / cell / "report.json").read_text())
        assert own["collision"] is True and own["outcome"] == "failure"
        assert own["min_signed_distance"] == own["attack_min_signed_distance"] == report["min_signed_distance"]
    assert [rows[f"{cell}-on-cautious"]["collision"] for cell in CELLS] == [True, False]
    failing = [f"{CELLS[0]}-on-idm", f"{CELLS[0]}-on-cautious", f"{CELLS[1]}-on-idm"]
    assert summary["failures"] == 3
    root = ET.parse(tmp_path / "replayed" / "junit.xml").getroot()
    assert [case.get("name") for case in root.iter("testcase") if case.find("failure") is not None] == failing


def test_a_replay_cell_shipped_to_a_ray_worker_needs_none_of_the_campaigns_paths(serial, tmp_path, monkeypatch):
    """What a Ray worker does with a cell, here in this process: from the bag and the attack's report and
    errors as shipped, with the attack's folder gone and no bag looked up by path, it gives the folder a
    serial run gives (the replay still names the campaign's attack folder), written by the campaign."""
    from advperc_ros import application
    from advperc_ros import replay as replay_module
    from advperc_ros.campaign.execute import Shipped, place, run_cell, run_shipped_cell, shipped_attack
    from advperc_ros.params import resolve_bag

    attacks = tmp_path / "attacks"
    shutil.copytree(serial, attacks)
    campaign = tmp_path / "replay.yaml"
    campaign.write_text(yaml.safe_dump({"name": "small", "output": str(tmp_path / "out"), "replay": str(attacks)}))
    cell = spec.plan(spec.load_campaign(campaign))[0]
    assert run_cell(cell, tmp_path / "here").error is None
    bag, attack = Shipped.of(resolve_bag(cell.params)), shipped_attack(cell)
    shutil.rmtree(attacks)

    def nowhere(params):
        raise AssertionError(f"the worker looked up {params.bag} by path")

    monkeypatch.setattr(application, "resolve_bag", nowhere)
    monkeypatch.setattr(replay_module, "resolve_bag", nowhere)
    (tmp_path / "there").mkdir()
    result, folder = run_shipped_cell(cell, bag, attack)
    assert place(tmp_path / "there", result, folder).error is None
    here, there = tmp_path / "here" / cell.name, tmp_path / "there" / cell.name
    assert sorted(p.name for p in here.iterdir()) == sorted(p.name for p in there.iterdir())
    reports = [json.loads((folder / "replay.json").read_text()) for folder in (here, there)]
    assert [{k: v for k, v in report.items() if k != "wall_time_s"} for report in reports] == [
        {k: v for k, v in reports[0].items() if k != "wall_time_s"}] * 2
    assert reports[1]["attack"] == str(attacks / CELLS[0])


class _Page(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.rows, self.images, self.in_body = 0, [], False

    def handle_starttag(self, tag, attrs):
        self.in_body |= tag == "tbody"
        self.rows += tag == "tr" and self.in_body
        if tag == "img":
            self.images.append(dict(attrs)["src"])


def test_the_html_page_shows_every_cell_with_its_picture(serial):
    page = _Page()
    page.feed((serial / "summary.html").read_text())
    assert page.rows == len(CELLS)
    assert page.images == [f"{cell}/bev.png" for cell in CELLS]
    assert all((serial / image).is_file() for image in page.images)


@pytest.mark.parametrize("fields, field", [
    ({"oops": 1}, "oops"),
    ({"scenarios": "config/idm_lane_following.yaml"}, "scenarios"),
    ({"scenarios": ["nowhere.yaml"]}, "scenarios[0]"),
    ({"objectives": ["ndss"]}, "objectives"),
    ({"seeds": [0, -1]}, "seeds"),
    ({"seeds": [0, 0]}, "seeds"),
    ({"workers": 0}, "workers"),
    ({"executor": "threads"}, "executor"),
    ({"overrides": {"search.random.steps": -1}}, "overrides"),
    ({"overrides": {"seed": 3}}, "overrides"),
    ({"overrides": {"rollout_backend": "graph"}}, "overrides"),
    ({"planners": [{"name": "x", "planner": "nope"}]}, "planners"),
    ({"planners": [{"name": "x", "planner_params": {"min_gap": -1.0}}]}, "planners"),
    ({"planners": [{"name": "a b"}]}, "planners[0].name"),
    ({"thresholds": {"map": 0.5}}, "thresholds"),
    ({"thresholds": {"nds": float("nan")}}, "thresholds.nds"),
    ({"thresholds": {"nds_t": float("inf")}}, "thresholds.nds_t"),
    ({"thresholds": {"nds": 5.0}}, "thresholds.nds"),
    ({"thresholds": {"nds_t": -1.0}}, "thresholds.nds_t"),
    ({"thresholds": {"pem_ll": float("-inf")}}, "thresholds.pem_ll"),
    ({"replay": "."}, "scenarios"),
])
def test_a_bad_campaign_file_is_refused_before_any_work(repo, tmp_path, capsys, fields, field):
    output = tmp_path / "out"
    campaign = write_campaign(tmp_path / "bad.yaml", repo, output, **fields)
    capsys.readouterr()
    assert main(["campaign", str(campaign), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith(f"advperc: error: {campaign}: field '{field}'"), err
    assert not output.exists()


def test_executor_ray_without_ray_is_one_line(repo, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(spec, "find_spec", lambda name: None)
    campaign = write_campaign(tmp_path / "ray.yaml", repo, tmp_path / "out", executor="ray")
    capsys.readouterr()
    assert main(["campaign", str(campaign), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"advperc: error: {campaign}: field 'executor' is ray, but ray is not installed: " \
                  "pip install 'advperc_ros[ray]'"


def test_the_attack_progress_bar_ends_at_the_rollouts_run(repo, tmp_path, capsys):
    params = write_params(tmp_path / "params.yaml", repo, **SHORT)
    capsys.readouterr()
    assert main(["attack", str(params), "--output", str(tmp_path / "out")]) == 0
    captured = capsys.readouterr()
    rollouts = json.loads(captured.out)["rollouts"]
    last = captured.err.replace("\r", "\n").strip().splitlines()[-2]  # the line before "results written to"
    assert "100%" in last and f" {rollouts}/{rollouts} " in last and "best=" in last, last


def test_a_log_gets_a_line_per_rollout_a_person_can_read(repo, tmp_path):
    """What the orchestrator node logs under ros2 launch (no terminal for a bar): each rollout's count
    against the bar's total, its verdict, the best attack so far and the collisions found."""
    from advperc_ros.application import attack_to_folder
    from advperc_ros.params import load_params

    lines: list[str] = []
    folder, report = attack_to_folder(load_params(write_params(tmp_path / "p.yaml", repo, **SHORT)), tmp_path / "out",
                                      say=lines.append)
    rows = list(csv.DictReader((folder / "search_log.csv").open()))
    assert len(lines) == len(rows) == report["rollouts"]
    collided = 0
    for k, (line, row) in enumerate(zip(lines, rows), start=1):
        collided += row["collided"] == "True" and not row["inconclusive"]
        verdict = "collision" if row["collided"] == "True" else "no collision"
        assert line.startswith(f"rollout {k} of about ") and f": {verdict};" in line, line
        assert line.endswith(f"; {collided} collision{'s' * (collided != 1)} so far"), line
    assert lines[-1].startswith(f"rollout {len(rows)} of about {len(rows)}: ")
    assert f"best {report['objective']} {float(rows[-1]['best_metric']):.4f}" in lines[-1]


def test_the_docs_document_every_campaign_field(repo):
    section = (repo / "docs" / "campaigns.md").read_text()
    for field in spec.FIELDS:
        assert f"`{field}`" in section, field


@pytest.mark.parametrize("where", ["nothing can be made there", "a file"])
def test_an_output_that_cannot_be_a_folder_is_refused_before_any_work(repo, tmp_path, capsys, where):
    if where == "a file":
        output = tmp_path / "file"
        output.write_text("x")
    else:
        output = Path("/proc/advperc-campaign")  # root passes access() there: only trying tells
    campaign = write_campaign(tmp_path / "bad.yaml", repo, output)
    capsys.readouterr()
    assert main(["campaign", str(campaign), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"advperc: error: {campaign}: field 'output' {output}"), err


def test_every_objective_has_the_range_of_its_thresholds():
    from advperc_ros.core.search.problem import OBJECTIVES

    assert set(spec.THRESHOLD_RANGES) == set(OBJECTIVES)


def _tree(folder: Path) -> dict[str, bytes | None]:
    return {str(path.relative_to(folder)): path.read_bytes() if path.is_file() else None
            for path in sorted(folder.rglob("*"))}


@pytest.mark.parametrize("owner", ["the user's files", "another campaign's output"])
def test_a_folder_the_campaign_did_not_make_is_refused_and_left_untouched(serial, repo, tmp_path, capsys, owner):
    """A campaign never writes into, nor clears anything of, a folder that is not its own."""
    output = tmp_path / "mine"
    if owner == "the user's files":
        output.mkdir()
        (output / "notes.txt").write_text("mine")
        (output / ".draft.partial").mkdir()  # looks like a campaign's staging: must survive
        (output / ".draft.partial" / "keep.txt").write_text("mine too")
    else:
        shutil.copytree(serial, output)  # the module's campaign "small" of another file
    before = _tree(output)
    campaign = write_campaign(tmp_path / "other.yaml", repo, output)
    capsys.readouterr()
    assert main(["campaign", str(campaign), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"advperc: error: {campaign}: field 'output' {output} is a "
                                                         "folder that campaign 'small' of this file did not make"), err
    assert _tree(output) == before


@pytest.mark.parametrize("damage, says", [
    (lambda text: text[: len(text) // 2], "not a finished cell's report (Unterminated string"),
    (lambda text: "[1, 2]", "field 'config_hash' missing: not a finished cell's report"),
    (lambda text: json.dumps({k: v for k, v in json.loads(text).items() if k != "config_hash"}),
     "field 'config_hash' missing: not a finished cell's report"),
])
def test_a_resume_over_a_finished_cell_whose_report_is_damaged_is_one_line_and_exit_2(serial, campaign, tmp_path,
                                                                                     capsys, damage, says):
    output = tmp_path / "damaged"
    shutil.copytree(serial, output)
    report = output / CELLS[0] / "report.json"
    report.write_text(damage(report.read_text()))
    before = sorted(path.relative_to(output) for path in output.rglob("*"))
    capsys.readouterr()
    assert main(["campaign", str(campaign), "--output", str(output), "--quiet"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"advperc: error: {report}: ") and says in line, line
    assert sorted(path.relative_to(output) for path in output.rglob("*")) == before
