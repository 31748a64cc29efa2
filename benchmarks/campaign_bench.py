"""A campaign on 1 worker against 2 workers (and on Ray), side by side, and whether they agree.

    python benchmarks/campaign_bench.py [--campaign examples/campaign.yaml] [--runs process:2 ray:2 process:1]
                                        [--scenarios NAME ...] [--override search.random.steps=4 ...] [--keep FOLDER]

Each run is `advperc campaign CAMPAIGN --executor E --workers N --quiet` in a fresh process and a
fresh output folder (nothing is resumed; --keep keeps them); a run named twice (process:1 process:2
process:1 process:2) counts with its median, so a change in the machine's load hits both alike.
Printed per run: wall time, the CPU time of the campaign and its workers, and the load average
before and after (on a shared machine the speed-up moves with it); then each executor's speed-up
over process:1 (else the first run) and whether its summary.md (the table, which holds no timings)
is the same as the first run's. The issue's goal: 2 workers in at most 1/1.8 of 1 worker's time.
"""

import argparse
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


def children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run(campaign: Path, executor: str, workers: int, output: Path) -> tuple[float, float, str]:
    """(wall s, CPU s, summary.md) of one campaign run."""
    cpu, started = children_cpu(), time.perf_counter()
    subprocess.run([sys.executable, "-m", "advperc_ros.cli", "campaign", str(campaign), "--executor", executor,
                    "--workers", str(workers), "--output", str(output), "--quiet"], check=True, cwd=REPO, stdout=subprocess.DEVNULL,
                   env=dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, (str(REPO), os.environ.get("PYTHONPATH"))))))
    return time.perf_counter() - started, children_cpu() - cpu, (output / "summary.md").read_text()


def variant(campaign: Path, overrides: list[str], scenarios: list[str], folder: Path) -> Path:
    """The campaign with `name=value` overrides added (values read as YAML) and only the scenarios whose
    file names `scenarios` lists (all when empty), written beside the outputs."""
    if not overrides and not scenarios:
        return campaign
    document = yaml.safe_load(campaign.read_text())
    document.setdefault("overrides", {}).update({k: yaml.safe_load(v) for k, v in (o.split("=", 1) for o in overrides)})
    document["scenarios"] = [str((REPO / s) if (REPO / s).exists() else s) for s in document["scenarios"]
                             if not scenarios or Path(s).stem in scenarios]
    changed = folder / campaign.name
    changed.write_text(yaml.safe_dump(document))
    return changed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--campaign", default=str(REPO / "examples" / "campaign.yaml"))
    parser.add_argument("--runs", nargs="+", default=["process:2", "ray:2", "process:1"], help="executor:workers")
    parser.add_argument("--override", nargs="*", default=[], help="campaign overrides, e.g. search.random.steps=4")
    parser.add_argument("--scenarios", nargs="*", default=[], help="only these scenarios of the campaign (file names)")
    parser.add_argument("--keep", help="folder to keep the runs' outputs in (default: a temporary one)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="advperc-campaign-bench-") as temporary:
        folder = Path(args.keep or temporary)
        folder.mkdir(parents=True, exist_ok=True)
        campaign = variant(Path(args.campaign).resolve(), args.override, args.scenarios, folder)
        walls: dict[str, list[float]] = {}
        tables: list[str] = []
        for i, spec in enumerate(args.runs):
            executor, workers = spec.split(":")
            load = os.getloadavg()[0]
            wall, cpu, table = run(campaign, executor, int(workers), folder / f"{i}-{spec.replace(':', '-')}")
            walls.setdefault(spec, []).append(wall)
            tables.append(table)
            print(f"{spec:>10}: {wall:7.1f} s wall, {cpu:7.1f} s CPU, load average {load:.2f} -> "
                  f"{os.getloadavg()[0]:.2f}; same table as the first run: {'yes' if table == tables[0] else 'NO'}",
                  flush=True)
        base = "process:1" if "process:1" in walls else args.runs[0]
        print(f"\nspeed-up over {base} (medians):")
        for spec, times in walls.items():
            goal = f" (goal >= {GOAL})" if base == "process:1" and spec.endswith(":2") else ""
            print(f"{spec:>10}: {statistics.median(walls[base]) / statistics.median(times):.2f}{goal}")
        print(f"\n{tables[0]}")


if __name__ == "__main__":
    main()
