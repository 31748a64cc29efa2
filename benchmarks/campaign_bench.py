"""A campaign on 1 worker against 2 workers (and on Ray), side by side, whether they agree, and each
worker's peak memory.

    python benchmarks/campaign_bench.py [--campaign examples/campaign.yaml] [--runs process:2 ray:2 process:1]
                                        [--scenarios NAME ...] [--objectives nds_t] [--seeds 0]
                                        [--override search.random.steps=4 ...] [--ray-python .venv-ray/bin/python]
                                        [--recordings FOLDER | --no-recording] [--recording-planners idm obp]
                                        [--keep FOLDER]

Each run is `advperc campaign CAMPAIGN --executor E --workers N --quiet` in a fresh process and a
fresh output folder (nothing is resumed; --keep keeps them); a run named twice (process:1 process:2
process:1 process:2) counts with its median, so a change in the machine's load hits both alike. Ray
runs use --ray-python (ray and commonroad-io cannot share one environment: CI keeps ray in .venv-ray).
When the CommonRoad recordings are there (../shared/data/commonroad), the largest (by file size) is
imported once with `advperc import-commonroad` and attacked with IDM and ObP as two more scenarios.

Printed per run: wall time, the CPU time of the campaign and its workers (a Ray run's: the campaign's
own only, as Ray's workers are not reaped through it), and the load average before and after (on a shared machine the speed-up moves with it); then each executor's speed-up
over process:1 (else the first run) and whether its summary.md (the table, which holds no timings)
is the same as the first run's; then per scenario and planner the peak resident memory of a worker
running one of its cells (summary.json's worker_peak_rss_mib: Python, imports and the cell; the
largest over its cells), per run. The issue's goal: 2 workers in at most 1/1.8 of 1 worker's time.
"""

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parent.parent
GOAL = 1.8  # speed-up of 2 workers over 1
RECORDINGS = REPO.parent / "shared" / "data" / "commonroad"


def children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run(python: str, campaign: Path, executor: str, workers: int, output: Path) -> tuple[float, float, str, list[dict]]:
    """(wall s, CPU s, summary.md, summary.json's rows) of one campaign run."""
    cpu, started = children_cpu(), time.perf_counter()
    subprocess.run([python, "-m", "advperc_ros.cli", "campaign", str(campaign), "--executor", executor,
                    "--workers", str(workers), "--output", str(output), "--quiet"], check=True, cwd=REPO,
                   stdout=subprocess.DEVNULL,
                   env=dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, (str(REPO), os.environ.get("PYTHONPATH"))))))
    rows = json.loads((output / "summary.json").read_text())["cells"]
    return time.perf_counter() - started, children_cpu() - cpu, (output / "summary.md").read_text(), rows


def largest_recording(recordings: Path, folder: Path, planners: list[str]) -> list[str]:
    """The params files of the largest recording for `planners` (idm, obp), imported into `folder` (none
    when the recordings are not there)."""
    if not recordings.is_dir():
        return []
    xml = max(recordings.glob("*.xml"), key=lambda path: path.stat().st_size)
    bag = folder / xml.stem
    if not bag.is_dir():
        subprocess.run([sys.executable, "-m", "advperc_ros.cli", "import-commonroad", str(xml), "--output", str(bag)],
                       check=True, cwd=REPO, stdout=subprocess.DEVNULL, env=dict(os.environ, PYTHONPATH=str(REPO)))
    return [str(bag.with_name(f"{xml.stem}{'' if planner == 'idm' else '.' + planner}.yaml")) for planner in planners]


def variant(campaign: Path, args: argparse.Namespace, extra: list[str], folder: Path) -> Path:
    """The campaign with `name=value` overrides added (values read as YAML), only the scenarios whose
    file names `scenarios` lists (all when empty) and the `extra` ones, and the objectives and seeds
    given, written beside the outputs."""
    if not (args.override or args.scenarios or extra or args.objectives or args.seeds):
        return campaign
    document = yaml.safe_load(campaign.read_text())
    document.setdefault("overrides", {}).update({k: yaml.safe_load(v) for k, v in (o.split("=", 1) for o in args.override)})
    document["scenarios"] = [str((REPO / s) if (REPO / s).exists() else s) for s in document["scenarios"]
                             if not args.scenarios or Path(s).stem in args.scenarios] + extra
    document.update({key: value for key, value in (("objectives", args.objectives), ("seeds", args.seeds)) if value})
    changed = folder / campaign.name
    changed.write_text(yaml.safe_dump(document))
    return changed


def memory_table(rows: dict[str, list[dict]]) -> str:
    """Per scenario and planner (rows) and run (columns), the largest worker peak over its cells, MiB."""
    kinds = list(dict.fromkeys((row["scenario"], row["planner"]) for cells in rows.values() for row in cells))
    lines = ["| scenario | planner | " + " | ".join(rows) + " |", "|---|---|" + "---|" * len(rows)]
    for scenario, planner in kinds:
        peaks = [max((row["worker_peak_rss_mib"] or 0.0 for row in cells
                      if (row["scenario"], row["planner"]) == (scenario, planner)), default=0.0) for cells in rows.values()]
        lines.append(f"| {scenario} | {planner} | " + " | ".join(f"{peak:.0f}" for peak in peaks) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--campaign", default=str(REPO / "examples" / "campaign.yaml"))
    parser.add_argument("--runs", nargs="+", default=["process:2", "ray:2", "process:1"], help="executor:workers")
    parser.add_argument("--override", nargs="*", default=[], help="campaign overrides, e.g. search.random.steps=4")
    parser.add_argument("--scenarios", nargs="*", default=[], help="only these scenarios of the campaign (file names)")
    parser.add_argument("--objectives", nargs="*", default=[], help="these objectives instead of the campaign's")
    parser.add_argument("--seeds", nargs="*", type=int, default=[], help="these seeds instead of the campaign's")
    parser.add_argument("--ray-python", default=sys.executable, help="the python that runs the ray runs (its venv has ray)")
    parser.add_argument("--recordings", type=Path, default=RECORDINGS, help="CommonRoad recordings: the largest is added")
    parser.add_argument("--no-recording", action="store_true", help="leave the largest recording out")
    parser.add_argument("--recording-planners", nargs="+", default=["idm", "obp"], choices=("idm", "obp"),
                        help="planners to attack the recording with (a search tries each of its 70 agents once, and an ObP "
                             "rollout there takes seconds)")
    parser.add_argument("--keep", help="folder to keep the runs' outputs in (default: a temporary one)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="advperc-campaign-bench-") as temporary:
        folder = Path(args.keep or temporary)
        folder.mkdir(parents=True, exist_ok=True)
        recording = folder / "recording"
        extra = [] if args.no_recording else largest_recording(args.recordings, recording, args.recording_planners)
        campaign = variant(Path(args.campaign).resolve(), args, extra, folder)
        walls: dict[str, list[float]] = {}
        tables: list[str] = []
        rows: dict[str, list[dict]] = {}
        for i, spec in enumerate(args.runs):
            executor, workers = spec.split(":")
            load = os.getloadavg()[0]
            python = args.ray_python if executor == "ray" else sys.executable
            wall, cpu, table, cells = run(python, campaign, executor, int(workers), folder / f"{i}-{spec.replace(':', '-')}")
            walls.setdefault(spec, []).append(wall)
            rows.setdefault(spec, []).extend(cells)
            tables.append(table)
            print(f"{spec:>10}: {wall:7.1f} s wall, {cpu:7.1f} s CPU, load average {load:.2f} -> "
                  f"{os.getloadavg()[0]:.2f}; same table as the first run: {'yes' if table == tables[0] else 'NO'}",
                  flush=True)
        base = "process:1" if "process:1" in walls else args.runs[0]
        print(f"\nspeed-up over {base} (medians):")
        for spec, times in walls.items():
            goal = f" (goal >= {GOAL})" if base == "process:1" and spec.endswith(":2") else ""
            print(f"{spec:>10}: {statistics.median(walls[base]) / statistics.median(times):.2f}{goal}")
        print(f"\npeak resident memory of a worker, MiB (the largest over each kind's cells):\n{memory_table(rows)}")
        print(f"\n{tables[0]}")


if __name__ == "__main__":
    main()
