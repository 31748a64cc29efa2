"""Every CommonRoad recording attacked with every planner, through the commands a user runs.

    python benchmarks/recordings_bench.py                       # all recordings, IDM and ObP
    python benchmarks/recordings_bench.py --planners idm reactive --recordings USA_US101-1_1_T-1
    python benchmarks/recordings_bench.py --markdown            # the README's table
    python benchmarks/recordings_bench.py --method guided       # every attack with that search method
    python benchmarks/recordings_bench.py --errors all          # every attack over the extended error kinds
    python benchmarks/recordings_bench.py --planners idm --rules collision phantom_braking   # each rule attacked
    python benchmarks/recordings_bench.py --bundled --rules progress  # the five bundled configs, not the recordings
    python benchmarks/recordings_bench.py --planners idm --reactive   # traffic that brakes for the ego

Per recording: `advperc import-commonroad X.xml --output DIR/bag` once, then `advperc attack
DIR/bag.yaml` (IDM), `DIR/bag.obp.yaml` (ObP), `DIR/bag.reactive.yaml` (the third-party
commonroad-reactive-planner: run this script with the python of the venv holding the `reactive`
extra) or `DIR/bag.fiss.yaml` with one of fiss-planner's variants (`--planners fop fop_plus fiss
fiss_plus`, extra `fiss`). With `--rules`, every attack is run once per rule (`advperc attack --rule NAME`), a column per
rule; with `--reactive`, every attack under reactive traffic (`advperc attack --reactive`), each row
saying whether a reacting agent was made to brake beyond the comfort bound (the `forced_braking`
rule) and how many agents left their recording; with `--bundled`, the bundled configs (config/*.yaml,
each with its own planner) are attacked
instead of the recordings. The outcome is the command's: an attack (NDS / NDS-t of the attack found),
no attack and why (report.json's message), refused (exit 1: the ground truth already breaks the rule,
or another refusal), rejected (exit 3, import-commonroad's reason). Attacks run on a process pool
(default 2 workers: the machine is shared), the longest expected first; wall time is each attack command's,
import excluded.
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

import yaml

from advperc_ros.core.rules.registry import RULES
from advperc_ros.core.rules.verdict import CONTACT_RULES, DEFAULT_RULE
from advperc_ros.core.search.registry import METHODS

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data" / "commonroad"
FISS_VARIANTS = ("fop", "fop_plus", "fiss", "fiss_plus")  # fiss-planner's four, from import-commonroad's bag.fiss.yaml
PLANNERS = ("idm", "obp", "reactive", *FISS_VARIANTS)
BUNDLED = ("idm_lane_following", "idm_overtake_follow", "obp_overtake", "obp_left_turn", "obp_right_turn")


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
    rule: str = DEFAULT_RULE  # the rule attacked (rows written before --rules have none)
    truth_value: float | None = None  # the attacked rule's value on the ground truth (report.json), null if infinite
    value: float | None = None  # the attacked rule's value on the attack's rollout
    traffic: str = "replayed"  # report.json's `traffic`
    forced: bool | None = None  # (reactive) the attack made a reacting agent brake beyond the bound (forced_braking)
    deviated: int | None = None  # (reactive) agents of the attack's rollout that left their recording


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
    """The params file import-commonroad wrote beside the bag for `planner`; for one of fiss-planner's
    variants, its bag.fiss.yaml with that variant (written beside it once)."""
    if planner not in FISS_VARIANTS:
        return bag.with_name({"idm": "bag.yaml", "obp": "bag.obp.yaml", "reactive": "bag.reactive.yaml"}[planner])
    variant = bag.with_name(f"bag.{planner}.yaml")
    if not variant.is_file():
        document = yaml.safe_load(bag.with_name("bag.fiss.yaml").read_text())
        document["orchestrator"]["ros__parameters"]["planner_params"]["variant"] = planner
        variant.write_text(yaml.safe_dump(document, sort_keys=False))
    return variant


@dataclass(frozen=True)
class Job:
    """One attack to run: what it is called in the table, the bag it reads, the params file it runs and
    where its results go (None: rejected on import, for `rejected`'s reason)."""

    name: str
    planner: str
    bag: Path | None
    params: Path | None
    folder: Path
    rejected: str = ""


def recording_job(name: str, planner: str, bag: Path | None, rejected: str, folder: Path) -> Job:
    """A recording's attack with `planner`, from the params file import-commonroad wrote beside its bag."""
    return Job(name, planner, bag, None if bag is None else params_file(bag, planner), folder, rejected)


def bundled_job(name: str, keep: Path) -> Job:
    """A bundled config's attack, with the planner it names."""
    params = REPO / "config" / f"{name}.yaml"
    planner = yaml.safe_load(params.read_text())["orchestrator"]["ros__parameters"]["planner"]
    return Job(name, planner, REPO / "bags" / name, params, keep / name)


def expected_cost(job: Job) -> tuple[bool, int]:
    """The order attacks start in, the longest expected first, so that the pool's last minutes are not one long
    attack alone (a longest-first schedule): every planner but IDM, whose frame costs a thousandth of ObP's, before
    IDM, and the recordings with the most vehicle-frames first (what the drops and the planner's frames grow with).
    The rows are the same in any order."""
    if job.bag is None:
        return True, 0
    from advperc_ros.ros.bag import read_scenario

    agents = read_scenario(job.bag).agents
    return job.planner == "idm", -int(agents.valid.sum())


def attack(job: Job, method: str | None = None, errors: str | None = None, rule: str | None = None,
           reactive: bool = False) -> Row:
    """The row of one attack (`method`: the search method, `errors`: errors.kinds, `rule`: the rule attacked;
    None: the params file's); with --keep, a row written by an earlier run is read back instead (so a killed
    benchmark resumes)."""
    parts = (method, errors, rule, "reactive" if reactive else None)
    cell = "-".join([job.planner, *(part for part in parts if part)]).replace(",", "+")
    written = job.folder / f"row-{cell}.json"
    if job.params is not None and written.is_file():
        return Row(**json.loads(written.read_text()))
    row = _attack(job, method, errors, rule, cell, reactive)
    if job.params is not None and row.outcome != "error":
        written.write_text(json.dumps(asdict(row)))
    return row


def _attack(job: Job, method: str | None, errors: str | None, rule: str | None, cell: str, reactive: bool) -> Row:
    recording, planner, attacked = job.name, job.planner, rule or DEFAULT_RULE
    if job.bag is None or job.params is None:
        return Row(recording, planner, None, None, "rejected", job.rejected, None, None, None, 0.0, attacked)
    from advperc_ros.ros.bag import read_scenario

    scenario = read_scenario(job.bag)
    vehicles, frames = scenario.agents.shape[1], scenario.num_frames
    job.folder.mkdir(parents=True, exist_ok=True)
    out = job.folder / f"res-{cell}"
    for left in (out, out.with_name(f".{out.name}.checkpoint")):  # by a killed run: its attack starts again
        if left.exists():
            shutil.rmtree(left)
    started = time.perf_counter()
    done = advperc("attack", str(job.params), "--output", str(out), "--quiet",
                   *(("--method", method) if method else ()), *(("--errors", errors) if errors else ()),
                   *(("--rule", rule) if rule else ()), *(("--reactive",) if reactive else ()))
    wall = time.perf_counter() - started
    said = [line for line in done.stderr.splitlines() if line.startswith("advperc: ")]  # not a library's noise
    last = said[-1] if said else ""
    if done.returncode != 0:
        # exit 1 is a refusal only with our one line; a traceback also exits 1, and is an error to see
        kind = "refused" if done.returncode == 1 and said else "error"
        reason = last or (done.stderr.strip().splitlines() or [f"exit {done.returncode}"])[-1]
        return Row(recording, planner, vehicles, frames, kind, reason, None, None, None, wall, attacked)
    report = json.loads((out / "report.json").read_text())
    truth = (report.get("ground_truth_rules") or {}).get(attacked, {}).get("value")
    traffic = report["traffic"]
    if report["collision"]:
        broken = report["rules"][attacked]
        where = (f"agent {report['collision_agent']} at frame {report['collision_frame']}"
                 if attacked == DEFAULT_RULE else f"{attacked} {broken['value']} from frame {broken['frame']}")
        reacted = report.get("deviated_agents")
        return Row(recording, planner, vehicles, frames, "attack", where, report["nds"], report["nds_t"],
                   report["rollouts"], wall, attacked, truth, broken["value"], traffic,
                   None if reacted is None else report["rules"]["forced_braking"]["violated"],
                   None if reacted is None else len(reacted))
    return Row(recording, planner, vehicles, frames, "no attack", report["message"], None, None, report["rollouts"],
               wall, attacked, truth, traffic=traffic)


def short(row: Row) -> str:
    """The outcome in a few words, for the table (the whole reason is in --json)."""
    if row.outcome == "attack":
        forced = ", one forced to brake hard" if row.forced else ""
        reacted = "" if row.deviated is None else f"; {row.deviated} agent{'s' * (row.deviated != 1)} reacted{forced}"
        return f"attack, NDS {row.nds:.3f} / NDS-t {row.nds_t:.3f}{reacted}"
    if row.outcome == "no attack":
        # a rule's r has the rule's unit; the contact rules' is a distance (m)
        value, unit = r"(-?[\d.]+|inf)", " m" if row.rule in CONTACT_RULES else ""
        closest = re.findall(r"closest approach (-?[\d.]+) m", row.reason)
        reached = re.search(rf"approach phase\) brought .* from {value}(?: m)? to {value}", row.reason)
        approach = f"; approach phase {reached.group(1)}{unit} to {reached.group(2)}{unit}" if reached else ""
        truth = "" if row.rule in CONTACT_RULES or row.truth_value is None else f"ground truth r = {row.truth_value:.3g}; "
        if "even with every vehicle hidden" in row.reason:  # its at-fault margin (or the rule's r), when it differs
            blind = re.search(rf"{value} m where a contact would be its fault|does not break \S+ \(r = {value}\)",
                              row.reason)
            margin = next((group for group in blind.groups() if group), None) if blind else closest[-1]
            return f"none: {truth}clear even blind ({margin}{unit}){approach}"
        return f"none: {truth}no influential vehicle{f' ({closest[0]} m)' if closest else ''}"
    if row.outcome == "refused":
        if "already breaks rule" in row.reason:
            return "refused: the ground truth breaks it"
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
    parser.add_argument("--rules", nargs="+", choices=tuple(RULES), metavar="RULE",
                        help="attack each of these rules (advperc attack --rule), a column each (default: the params "
                        f"files' rule): {', '.join(RULES)}")
    parser.add_argument("--bundled", action="store_true", help="attack the five bundled configs (config/*.yaml, each "
                        "with its own planner; --planners and --data unused) instead of the recordings")
    parser.add_argument("--reactive", action="store_true", help="every attack under reactive traffic "
                        "(advperc attack --reactive): agents keep their recorded paths but brake for the ego")
    parser.add_argument("--json", type=Path, help="also write the rows here")
    parser.add_argument("--keep", type=Path, help="write bags and results folders here (default: a temporary folder)")
    parser.add_argument("--markdown", action="store_true", help="print the table as Markdown")
    args = parser.parse_args()
    names = args.recordings or (list(BUNDLED) if args.bundled else sorted(p.stem for p in args.data.glob("*.xml")))
    if not names:
        sys.exit(f"{args.data}: no CommonRoad recordings")
    rules = args.rules or [None]
    with tempfile.TemporaryDirectory(prefix="recordings-bench-") as scratch, ThreadPoolExecutor(args.workers) as pool:
        tmp = Path(args.keep or scratch)
        if args.bundled:
            jobs = [bundled_job(n, tmp) for n in names]
        else:
            imported = dict(zip(names, pool.map(lambda n: import_recording(args.data / f"{n}.xml", tmp / n), names)))
            jobs = [recording_job(n, p, *imported[n], tmp / n) for n in names for p in args.planners]
        cells = sorted(((job, rule) for job in jobs for rule in rules), key=lambda cell: expected_cost(cell[0]))
        rows = list(pool.map(lambda cell: attack(cell[0], args.method, args.errors, cell[1], args.reactive), cells))
        for row in rows:
            print(json.dumps(asdict(row)), file=sys.stderr, flush=True)
    if args.json:
        args.json.write_text(json.dumps([asdict(r) for r in rows], indent=1))
    print_table(names, rows, ["planner"] if args.bundled else args.planners, rules, args.markdown)


def print_table(names: list[str], rows: list[Row], planners: list[str], rules: list[str | None], markdown: bool) -> None:
    """A line per recording (or bundled config), a column per planner and rule attacked (a bundled config's
    planner is its own), and how many were attacked; with a contact rule's column among rules, how many of the
    recordings it finds nothing on each other rule attacks."""
    columns = [(p, r or DEFAULT_RULE) for p in planners for r in rules]
    by = {(row.recording, "planner" if planners == ["planner"] else row.planner, row.rule): row for row in rows}
    if markdown:
        labels = [" ".join(part for part in (p if p != "planner" else "", r if rules != [None] else "") if part) or p
                  for p, r in columns]
        head = ["recording", "vehicles", "frames", *labels]
        print("| " + " | ".join(head) + " |\n|" + "---|" * len(head))
    for name in names:
        first = by[(name, *columns[0])]
        cells = [name, str(first.vehicles or "-"), str(first.frames or "-")]
        cells += [short(by[name, p, r]) + (f"; {by[name, p, r].rollouts or 0} rollouts, {by[name, p, r].wall_s:.0f} s"
                                            if by[name, p, r].outcome != "rejected" else "") for p, r in columns]
        print(("| " + " | ".join(cells) + " |") if markdown else "\t".join(cells))
    found = sum(any(by[n, p, r].outcome == "attack" for p, r in columns) for n in names)
    print(f"\n{found}/{len(names)} attacked by at least one planner and rule")
    reacting = [row for row in rows if row.outcome == "attack" and row.deviated is not None]
    if reacting:
        print(f"reactive traffic: {sum(row.deviated > 0 for row in reacting)} of {len(reacting)} attacks made an agent "
              f"react, {sum(bool(row.forced) for row in reacting)} forced one to brake beyond the comfort bound")
    contact = next((r for r in rules if r in CONTACT_RULES), None)
    others = [r for r in rules if r is not None and r not in CONTACT_RULES]
    for planner in planners if contact is not None and others else ():
        unattacked = [n for n in names if by[n, planner, contact].outcome == "no attack"]
        for rule in others:
            through = sum(by[n, planner, rule].outcome == "attack" for n in unattacked)
            print(f"{planner}: {through} of the {len(unattacked)} where {contact} finds nothing are attacked through {rule}")
        anyone = sum(any(by[n, planner, r].outcome == "attack" for r in others) for n in unattacked)
        print(f"{planner}: {anyone} of the {len(unattacked)} where {contact} finds nothing are attacked through "
              f"{', '.join(others)}")


if __name__ == "__main__":
    main()
