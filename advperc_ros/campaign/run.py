"""One run of a campaign: check it whole, take its output folder, clear what killed cells left, run the
cells not finished yet on the executor, and keep the summary current after every cell, so a campaign
killed at any point is resumed by running it again.
"""

import json
import shutil
import sys
from collections import deque
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from advperc_ros.backends.resumed import checkpoint_folder
from advperc_ros.campaign.execute import CellResult, executor
from advperc_ros.campaign.spec import ATTACK, Campaign, Cell, finished_report, plan, transfer_cells
from advperc_ros.campaign.summary import (
    ERROR,
    FAILURE,
    SUMMARY_JSON,
    CellStatus,
    verdict,
    write_summary,
)
from advperc_ros.exits import EXIT_OK
from advperc_ros.results.destination import exclusive

LOCK = ".campaign.lock"
EXIT_BUG = 1  # what Python exits with on an uncaught exception


@dataclass(frozen=True)
class CampaignRun:
    """What a campaign run did: which cells ran now and which a resumed run found finished, so a
    resumed campaign says how much work it saved, and the exit code a CI job acts on."""

    output: Path
    ran: tuple[str, ...]  # cells run now
    finished_before: tuple[str, ...]  # cells found finished and not run again
    records: list[dict]  # the summary's rows
    exit_code: int  # EXIT_OK, else the first failed cell's (a bug counts as EXIT_BUG)

    def summary(self) -> dict:
        outcomes = [r["outcome"] for r in self.records]
        return {"output": str(self.output), "cells": len(self.records), "ran": len(self.ran),
                "finished_before": len(self.finished_before), "collide": sum(1 for r in self.records if r["collision"]),
                "failures": outcomes.count(FAILURE), "errors": outcomes.count(ERROR)}


def clear_staging(output: Path) -> None:
    """Hidden staging folders and files (.<name>.partial) are what a killed cell or summary left."""
    for stale in output.glob(".*.partial"):
        shutil.rmtree(stale) if stale.is_dir() else stale.unlink()


def refuse_foreign_output(campaign: Campaign) -> None:
    """A campaign writes only into a folder of its own: new, empty, or holding the summary of a campaign
    of the same name and file. Any other folder is the user's, and a campaign run there would write
    among their files and clear their `.*.partial` entries."""
    output = campaign.output
    if output.is_dir():
        found = sorted(entry.name for entry in output.iterdir() if entry.name != LOCK)
        if found and _summary_owner(output) != (campaign.name, str(campaign.source.resolve())):
            raise campaign.fail("output", f"{output} is a folder that campaign '{campaign.name}' of this file did not "
                                          f"make (it holds {found[0]!r}, and no {SUMMARY_JSON} of this campaign): "
                                          "choose a new or empty folder")


def _summary_owner(output: Path) -> tuple[str, str] | None:
    """(campaign name, campaign file) of the summary a campaign wrote in `output`, None if there is none."""
    try:
        summary = json.loads((output / SUMMARY_JSON).read_text())
        return summary["campaign"], summary["source"]
    except (OSError, ValueError, TypeError, KeyError):
        return None


def _earlier_memory(output: Path) -> dict[str, float]:
    """The workers' peak memory per cell that an earlier run of this campaign recorded in its summary
    (the cell folders do not hold it), so a resumed campaign's summary still has it."""
    try:
        rows = json.loads((output / SUMMARY_JSON).read_text())["cells"]
        return {row["cell"]: row["worker_peak_rss_mib"] for row in rows if row.get("worker_peak_rss_mib") is not None}
    except (OSError, ValueError, TypeError, KeyError):
        return {}


def run_campaign(campaign: Campaign, progress: bool = True) -> CampaignRun:
    refuse_foreign_output(campaign)
    cells = plan(campaign)  # everything checked before any work
    output = campaign.output.resolve()
    output.mkdir(parents=True, exist_ok=True)
    with exclusive(output / LOCK, f"{output}: another campaign run is using this folder"):  # it would start the same cells
        clear_staging(output)
        reports = {cell.name: cell.report(output) for cell in cells}
        attacks = [cell for cell in cells if cell.role == ATTACK]

        def transfers(found: Cell) -> list[Cell]:
            """The replays of `found`'s attack on the campaign's other planners, once it is known to break its
            rule; their finished reports read (and refused when finished with other params)."""
            report = reports[found.name]
            if found.role != ATTACK or not report or not report.get("collision"):
                return []
            replays = transfer_cells(attacks, found, output)
            reports.update({replay.name: finished_report(campaign, replay) for replay in replays})
            return replays

        cells += [replay for cell in list(cells) for replay in transfers(cell)]
        for name in (name for name, report in reports.items() if report is not None):
            # a cell killed after its results folder was in place, before its checkpoint went
            shutil.rmtree(checkpoint_folder(output / name), ignore_errors=True)
        todo = deque(cell for cell in cells if reports[cell.name] is None)
        before = tuple(cell.name for cell in cells if reports[cell.name] is not None)
        results: dict[str, CellResult] = {}
        running: set[str] = set()
        earlier = {name: mib for name, mib in _earlier_memory(output).items() if name in before}

        def status(cell: Cell) -> CellStatus:
            result = results.get(cell.name)
            if result is None:
                return CellStatus(cell, reports[cell.name], running=cell.name in running,
                                  peak_rss_mib=earlier.get(cell.name))
            return CellStatus(cell, reports[cell.name], result.error, cell.name in running, result.peak_rss_mib)

        def statuses() -> list[CellStatus]:
            return [status(cell) for cell in cells]

        say = (lambda line: tqdm.write(line, file=sys.stderr)) if progress else (lambda line: None)
        bar = tqdm(total=len(cells), initial=len(before), desc=f"campaign {campaign.name}", unit="cell",
                   disable=not progress, file=sys.stderr)
        in_flight = 1 if campaign.executor == "serial" else campaign.workers
        say(f"campaign {campaign.name}: {len(cells)} cells, {len(before)} finished before, {len(todo)} to run "
            f"({campaign.executor}, {in_flight} at a time) into {output}")
        records = write_summary(campaign, output, statuses())
        by_name = {cell.name: cell for cell in cells}
        pool = executor(campaign, output, progress) if todo else None
        try:
            while todo or running:
                assert pool is not None  # made whenever a cell is to run
                while todo and len(running) < in_flight:
                    cell = todo.popleft()
                    pool.submit(cell)
                    running.add(cell.name)
                    say(f"started  {cell.name}")
                bar.set_postfix_str(f"{len(running)} running", refresh=True)
                result = pool.next_done()
                running.discard(result.name)
                bar.set_postfix_str(f"{len(running)} running", refresh=False)
                reports[result.name] = by_name[result.name].report(output)
                results[result.name] = result
                replays = transfers(by_name[result.name])  # its attack, on the other planners: before more attacks,
                for replay in reversed(replays):  # as they take seconds, and the matrix fills in as the campaign goes
                    by_name[replay.name] = replay
                    todo.appendleft(replay)
                cells += replays
                bar.total = len(cells)
                records = write_summary(campaign, output, statuses())
                say(f"finished {result.name}: {verdict(status(by_name[result.name]), dict(campaign.thresholds)).text}")
                bar.update()
        finally:
            if pool is not None:
                pool.close()
            bar.close()
    failed = [results[cell.name] for cell in cells if cell.name in results and results[cell.name].error is not None]
    code = EXIT_OK if not failed else (failed[0].exit_code if failed[0].exit_code is not None else EXIT_BUG)
    return CampaignRun(output, tuple(results), before, records, code)
