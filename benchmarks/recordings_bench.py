"""Every CommonRoad recording attacked with every planner, through the commands a user runs.

    python benchmarks/recordings_bench.py                       # all recordings, IDM and ObP
    python benchmarks/recordings_bench.py --planners idm reactive --recordings USA_US101-1_1_T-1
    python benchmarks/recordings_bench.py --markdown            # the README's table
    python benchmarks/recordings_bench.py --method guided       # every attack with that search method
    python benchmarks/recordings_bench.py --errors all          # every attack over the extended error kinds

Per recording: `advperc import-commonroad X.xml --output DIR/bag` once, then `advperc attack
DIR/bag.yaml` (IDM), `DIR/bag.obp.yaml` (ObP) or `DIR/bag.reactive.yaml` (the third-party
commonroad-reactive-planner: run this script with the python of the venv holding the `reactive`
extra). The outcome is the command's: an attack (NDS / NDS-t of the attack found), no attack and
why (report.json's message), refused (exit 1), rejected (exit 3, import-commonroad's reason). Attacks run on a process pool (default 2 workers:
the machine is shared); wall time is each attack command's, import excluded.
"""

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

from advperc_ros.core.search.registry import METHODS

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data" / "commonroad"
PLANNERS = ("idm", "obp", "reactive")


@dataclass(frozen=True)
class Row:
    recording: str
    planner: str
    vehicles: int | None
    frames: int | None
    outcome: str  # attack | no attack | refused | rejected | error
    reason: str
    nds: float | None
    nds_t: float | None
    rollouts: int | None
    wall_s: float


def advperc(*args: str) -> subprocess.CompletedProcess:
    """The `advperc` command of this checkout (not whichever advperc_ros is installed)."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run([sys.executable, "-m", "advperc_ros.cli", *args], capture_output=True, text=True, env=env)


def import_recording(xml: Path, folder: Path) -> tuple[Path | None, str]:
    """(bag, message): the bag imported into `folder` (kept from an earlier run with --keep), or None and why
    it was rejected."""
    if (folder / "bag").is_dir():
        return folder / "bag", "imported before"
    done = advperc("import-commonroad", str(xml), "--output", str(folder / "bag"))
    if done.returncode != 0:
        return None, done.stderr.strip().splitlines()[-1] if done.stderr.strip() else f"exit {done.returncode}"
    return folder / "bag", done.stdout


def params_file(bag: Path, planner: str) -> Path:
    """The params file import-commonroad wrote beside the bag for `planner`."""
    return bag.with_name({"idm": "bag.yaml", "obp": "bag.obp.yaml", "reactive": "bag.reactive.yaml"}[planner])


def attack(recording: str, planner: str, bag: Path | None, rejected: str, method: str | None = None,
           errors: str | None = None) -> Row:
    """The row of one attack (`method`: the search method, `errors`: errors.kinds, None: the params file's); with
    --keep, a row written by an earlier run is read back instead (so a killed benchmark resumes)."""
    cell = "-".join([planner, *(part for part in (method, errors) if part)]).replace(",", "+")
    if bag is not None and bag.with_name(f"row-{cell}.json").is_file():
        return Row(**json.loads(bag.with_name(f"row-{cell}.json").read_text()))
    row = _attack(recording, planner, bag, rejected, method, errors, cell)
    if bag is not None and row.outcome != "error":
        bag.with_name(f"row-{cell}.json").write_text(json.dumps(asdict(row)))
    return row


def _attack(recording: str, planner: str, bag: Path | None, rejected: str, method: str | None, errors: str | None,
            cell: str) -> Row:
    if bag is None:
        return Row(recording, planner, None, None, "rejected", rejected, None, None, None, 0.0)
    from advperc_ros.ros.bag import read_scenario  # noqa: PLC0415 (the parent process needs no ROS types)

    scenario = read_scenario(bag)
    vehicles, frames = scenario.agents.shape[1], scenario.num_frames
    out = bag.with_name(f"res-{cell}")
    for left in (out, out.with_name(f".{out.name}.checkpoint")):  # by a killed run: its attack starts again
        if left.exists():
            shutil.rmtree(left)
    started = time.perf_counter()
    done = advperc("attack", str(params_file(bag, planner)), "--output", str(out), "--quiet",
                   *(("--method", method) if method else ()), *(("--errors", errors) if errors else ()))
    wall = time.perf_counter() - started
    said = [line for line in done.stderr.splitlines() if line.startswith("advperc: ")]  # not a library's noise
    last = said[-1] if said else ""
    if done.returncode != 0:
        # exit 1 is a refusal only with our one line; a traceback also exits 1, and is an error to see
        kind = "refused" if done.returncode == 1 and said else "error"
        reason = last or (done.stderr.strip().splitlines() or [f"exit {done.returncode}"])[-1]
        return Row(recording, planner, vehicles, frames, kind, reason, None, None, None, wall)
    report = json.loads((out / "report.json").read_text())
    if report["collision"]:
        return Row(recording, planner, vehicles, frames, "attack",
                   f"agent {report['collision_agent']} at frame {report['collision_frame']}",
                   report["nds"], report["nds_t"], report["rollouts"], wall)
    return Row(recording, planner, vehicles, frames, "no attack", report["message"], None, None, report["rollouts"],
               wall)


def short(row: Row) -> str:
    """The outcome in a few words, for the table (the whole reason is in --json)."""
    if row.outcome == "attack":
        return f"attack, NDS {row.nds:.3f} / NDS-t {row.nds_t:.3f}"
    if row.outcome == "no attack":
        closest = re.findall(r"closest approach (-?[\d.]+) m", row.reason)
        reached = re.search(r"approach phase\) brought .* from (-?[\d.]+) m to (-?[\d.]+) m", row.reason)
        approach = f"; approach phase {reached.group(1)} m to {reached.group(2)} m" if reached else ""
        if "even with every vehicle hidden" in row.reason:  # its at-fault margin, when it differs
            blind = re.search(r"(-?[\d.]+) m where a contact would be its fault", row.reason)
            return f"none: clear even blind ({blind.group(1) if blind else closest[-1]} m){approach}"
        return f"none: no influential vehicle ({closest[0]} m)" if closest else "none"
    if row.outcome == "refused":
        found = re.search(r"min signed distance (-?[\d.]+) m", row.reason)
        return (f"refused: at-fault collision unattacked ({found.group(1)} m)" if found
                else f"refused: {row.reason.removeprefix('advperc: ')}")
    if row.outcome == "rejected":
        found = re.search(r"overlaps by ([\d.]+) m", row.reason)
        return (f"rejected: unavoidable (overlap {found.group(1)} m)" if found
                else f"rejected: {row.reason.removeprefix('advperc: error: ')}")
    return f"error: {row.reason}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=DATA, help="folder of CommonRoad XML files")
    parser.add_argument("--recordings", nargs="+", help="file stems (default: every .xml in --data)")
    parser.add_argument("--planners", nargs="+", choices=PLANNERS, default=("idm", "obp"))
    parser.add_argument("--workers", type=int, default=2, help="attacks run at once (each one process)")
    parser.add_argument("--method", choices=METHODS, help="the search method of every attack (default: the params files')")
    parser.add_argument("--errors", metavar="KINDS", help="errors.kinds of every attack: paper, all, or a list "
                        "(default: the params files')")
    parser.add_argument("--json", type=Path, help="also write the rows here")
    parser.add_argument("--keep", type=Path, help="write bags and results folders here (default: a temporary folder)")
    parser.add_argument("--markdown", action="store_true", help="print the table as Markdown")
    args = parser.parse_args()
    names = args.recordings or sorted(p.stem for p in args.data.glob("*.xml"))
    if not names:
        sys.exit(f"{args.data}: no CommonRoad recordings")
    with tempfile.TemporaryDirectory(prefix="recordings-bench-") as scratch, ThreadPoolExecutor(args.workers) as pool:
        tmp = args.keep or scratch
        imported = dict(zip(names, pool.map(lambda n: import_recording(args.data / f"{n}.xml", Path(tmp) / n), names)))
        jobs = [(n, p) for n in names for p in args.planners]
        rows = list(pool.map(lambda job: attack(job[0], job[1], *imported[job[0]], args.method, args.errors), jobs))
        for row in rows:
            print(json.dumps(asdict(row)), file=sys.stderr, flush=True)
    if args.json:
        args.json.write_text(json.dumps([asdict(r) for r in rows], indent=1))
    by = {(r.recording, r.planner): r for r in rows}
    if args.markdown:
        head = ["recording", "vehicles", "frames", *args.planners]
        print("| " + " | ".join(head) + " |\n|" + "---|" * len(head))
    for name in names:
        first = by[name, args.planners[0]]
        cells = [name, str(first.vehicles or "-"), str(first.frames or "-")]
        cells += [short(by[name, p]) + (f"; {by[name, p].rollouts or 0} rollouts, {by[name, p].wall_s:.0f} s"
                                         if by[name, p].outcome != "rejected" else "") for p in args.planners]
        print(("| " + " | ".join(cells) + " |") if args.markdown else "\t".join(cells))
    found = sum(any(by[n, p].outcome == "attack" for p in args.planners) for n in names)
    print(f"\n{found}/{len(names)} recordings attacked by at least one planner")


if __name__ == "__main__":
    main()
