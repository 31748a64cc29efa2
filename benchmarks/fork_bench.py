"""Forked rollouts against full ones: the default search of each scenario with and without forking, side by
side in one run (docs/results.md, "Forked rollouts").

Per scenario (a bundled config, or a CommonRoad recording imported into a temporary folder, with each
`--planners` params file import-commonroad wrote), `advperc attack` twice: in full, with `--fork-memory 0` and
ObP's solve memo off (`ADVPERC_OBP_MEMO=0`: every rollout from frame 0, every planning call solved), and as a
user runs it (the params' own fork_memory, the memo on), the order alternating from one scenario to the next
as the machine's speed drifts. `--memo-alone` also runs it with the memo and no forks. Prints per attack the
wall times, their ratio, the frames the forked search drove over the frames of its rollouts, the snapshots'
peak memory and each attack's largest resident set, and whether the two wrote the same search_log.csv,
attack_errors.npz and report.json (wall time aside); the last line is the median ratio and whether every pair
was identical. `--before TREE` also runs each attack with the code of TREE, a checkout of an earlier commit
(`git worktree add TREE REV`), as it was: the wall time before and after, and whether it wrote the same
results. `--virtual-machine` also runs each forked attack with ObP's NLP on CasADi's virtual machine
(`ADVPERC_COMPILE_NLP=0`) instead of its compiled library (docs/obp.md, "Compiled NLP"): the wall time of
each, and whether they wrote the same results.

    python benchmarks/fork_bench.py --scenarios obp_overtake
    python benchmarks/fork_bench.py --scenarios --recordings USA_US101-22_1_T-1 --planners idm obp
    python benchmarks/fork_bench.py --scenarios obp_overtake --before ../before
    python benchmarks/fork_bench.py --scenarios obp_overtake obp_left_turn obp_right_turn --virtual-machine
    python benchmarks/fork_bench.py --scenarios obp_overtake --memo-alone
"""

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from recordings_bench import params_file

from advperc_ros.core.planners.obp.compiled import SWITCH_ENV
from advperc_ros.core.planners.obp.planner import MEMO_ENV

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data" / "commonroad"
BUNDLED = ("idm_lane_following", "idm_overtake_follow", "obp_overtake", "obp_left_turn", "obp_right_turn")
VOLATILE = {"wall_time_s"}  # of report.json: what two runs of one attack may differ in
# the CLI, with the embedded backend's summary of what forking saved (a DEBUG line) let through
CHILD = ("import logging, sys; logging.getLogger('advperc_ros.backends.embedded').setLevel(logging.DEBUG); "
         "from advperc_ros.cli import main; sys.exit(main(sys.argv[1:]))")
SUMMARY = re.compile(r"(\d+) of (\d+) rollouts forked from a snapshot; (\d+) of (\d+) frames driven .*at most ([\d.]+) of")


@dataclass(frozen=True)
class Run:
    """One attack: its wall time, exit code, largest resident set, and what the forked one's log said."""

    wall: float
    code: int
    rss_mib: float
    stderr: str


def attack(params: Path, output: Path, fork_memory: int | None, tree: Path | None = None,
           env_extra: dict[str, str] | None = None) -> Run:
    """`advperc attack params --output output` in a child process (with the code of `tree` when given, and the
    environment's variables `env_extra` set), timed, its own rusage read at its exit."""
    command = [sys.executable, "-c", CHILD, "attack", str(params), "--quiet", "--output", str(output)]
    if fork_memory is not None:
        command += ["--fork-memory", str(fork_memory)]
    # in the tree, so that `python -c` (which puts the working folder first on sys.path) imports its code
    env = {**os.environ, **(env_extra or {}), **({} if tree is None else {"PYTHONPATH": str(tree.resolve())})}
    started = time.perf_counter()
    child = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env,
                             cwd=None if tree is None else tree)
    stderr = child.stderr.read() if child.stderr is not None else ""
    _, status, usage = os.wait4(child.pid, 0)
    child.returncode = os.waitstatus_to_exitcode(status)
    return Run(time.perf_counter() - started, child.returncode, usage.ru_maxrss / 1024, stderr)


def same_results(a: Path, b: Path) -> bool:
    """Whether two results folders hold the same search log, attack and report (wall time aside)."""
    for name in ("search_log.csv", "attack_errors.npz"):
        if (a / name).is_file() != (b / name).is_file():
            return False
        if (a / name).is_file() and (a / name).read_bytes() != (b / name).read_bytes():
            return False
    reports = [{k: v for k, v in json.loads((f / "report.json").read_text()).items() if k not in VOLATILE}
               for f in (a, b) if (f / "report.json").is_file()]
    return len(reports) in (0, 2) and (not reports or reports[0] == reports[1])


def measure(name: str, params: Path, scratch: Path, forked_first: bool, before: Path | None,
            virtual_machine: bool = False, memo_alone: bool = False) -> tuple[float, bool]:
    """Both attacks of one params file (and the one of `before`, the forked one on the virtual machine, and the
    one with the solve memo and no forks), printed as a table row; (forked/full wall ratio, identical)."""
    runs: dict[str, Run] = {}
    order = ["forked", "full"] if forked_first else ["full", "forked"]
    extra = (["before"] if before is not None else []) + (["vm"] if virtual_machine else []) + (
        ["memo"] if memo_alone else [])
    environment = {"full": {MEMO_ENV: "0"}, "vm": {SWITCH_ENV: "0"}}
    for which in order + extra:
        runs[which] = attack(params, scratch / f"{name}-{which}", 0 if which in ("full", "memo") else None,
                             before if which == "before" else None, environment.get(which))
    forked, full = runs["forked"], runs["full"]
    identical = forked.code == full.code and same_results(scratch / f"{name}-forked", scratch / f"{name}-full")
    said = SUMMARY.search(forked.stderr)
    rollouts, frames, peak = ("?", "?", "?") if said is None else (
        f"{said[1]}/{said[2]}", f"{int(said[3]) / max(int(said[4]), 1):.2f}", said[5])
    ratio = forked.wall / full.wall
    then = ""
    if "before" in runs:
        same = runs["before"].code == full.code and same_results(scratch / f"{name}-before", scratch / f"{name}-full")
        then = f" {runs['before'].wall:.1f} | {forked.wall / runs['before'].wall:.2f} | {'yes' if same else 'no'} |"
    if "vm" in runs:
        same = runs["vm"].code == forked.code and same_results(scratch / f"{name}-vm", scratch / f"{name}-forked")
        then += f" {runs['vm'].wall:.1f} | {forked.wall / runs['vm'].wall:.2f} | {'yes' if same else 'no'} |"
    if "memo" in runs:
        same = runs["memo"].code == full.code and same_results(scratch / f"{name}-memo", scratch / f"{name}-full")
        then += f" {runs['memo'].wall:.1f} | {runs['memo'].wall / full.wall:.2f} | {'yes' if same else 'no'} |"
    print(f"| {name} | {full.code} | {full.wall:.1f} | {forked.wall:.1f} | {ratio:.2f} | {rollouts} | {frames} | {peak} | "
          f"{full.rss_mib:.0f} / {forked.rss_mib:.0f} | {'yes' if identical else 'no'} |{then}", flush=True)
    return ratio, identical


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenarios", nargs="*", default=BUNDLED, help="bundled configs (config/<name>.yaml)")
    parser.add_argument("--recordings", nargs="*", default=(), help="CommonRoad recordings (file stems in --data)")
    parser.add_argument("--planners", nargs="*", default=("idm", "obp"), help="the recordings' params files to attack")
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--before", type=Path, help="a checkout of an earlier commit: each attack with its code too")
    parser.add_argument("--virtual-machine", action="store_true",
                        help="each forked attack also with ObP's NLP on CasADi's virtual machine, not compiled")
    parser.add_argument("--memo-alone", action="store_true",
                        help="each attack also with ObP's solve memo and no forks (what the memo saves alone)")
    args = parser.parse_args()
    then = " before (s) | forked / before | same as before |" if args.before else ""
    then += " forked, VM (s) | compiled / VM | same on the VM |" if args.virtual_machine else ""
    then += " memo, no forks (s) | memo / full | same with the memo |" if args.memo_alone else ""
    print("| attack | exit | full (s) | forked (s) | forked / full | rollouts forked | frames driven / full | "
          f"snapshots peak (MiB) | max RSS full / forked (MiB) | identical |{then}")
    print("|---|---|---|---|---|---|---|---|---|---|" + ("---|---|---|" if args.before else "")
          + ("---|---|---|" if args.virtual_machine else "") + ("---|---|---|" if args.memo_alone else ""))
    ratios, identical = [], []
    with tempfile.TemporaryDirectory(prefix="fork-bench-") as folder:
        scratch = Path(folder)
        jobs = [(name, REPO / "config" / f"{name}.yaml") for name in args.scenarios]
        for name in args.recordings:
            bag = scratch / name / "bag"
            done = subprocess.run([sys.executable, "-m", "advperc_ros.cli", "import-commonroad",
                                   str(args.data / f"{name}.xml"), "--output", str(bag)], capture_output=True, text=True)
            if done.returncode != 0:
                print(f"| {name} | import-commonroad exit {done.returncode}: {done.stderr.strip()[-120:]} |")
                continue
            jobs += [(f"{name} {planner}", params_file(bag, planner)) for planner in args.planners]
        for i, (name, params) in enumerate(jobs):
            ratio, same = measure(name.replace(" ", "-"), params, scratch, i % 2 == 0, args.before, args.virtual_machine,
                                  args.memo_alone)
            ratios.append(ratio)
            identical.append(same)
    if not ratios:
        sys.exit("fork_bench: no attack ran (the rows above say why)")
    print(f"forked/full wall ratio {statistics.median(ratios):.2f}, identical: {'yes' if all(identical) else 'no'}")


if __name__ == "__main__":
    main()
