"""One attack from validated params to a results folder: what `advperc attack` and the
orchestrator node both call, so both choose the same output folder, check it before any work,
and write the same report."""

from pathlib import Path
from typing import Any

from advperc_ros.attack import open_rollouts, run_attack
from advperc_ros.params import AttackParams, ParamsError, resolve_bag
from advperc_ros.results import write_results
from advperc_ros.ros.bag import read_scenario


def default_output(params: AttackParams, scenario_name: str) -> Path:
    """results/<params file name, else scenario>-seed<N>, numbered on when taken."""
    stem = params.source.stem if params.source is not None else scenario_name
    base = Path("results") / f"{stem}-seed{params.seed}"
    candidate, n = base, 1
    while candidate.exists():
        n += 1
        candidate = base.with_name(f"{base.name}-{n}")
    return candidate


def attack_to_folder(params: AttackParams, output: Path | None, progress: bool = False,
                     transport: Any = None) -> tuple[Path, dict]:
    """Run the attack the params describe and write its results folder; (folder, report).
    `transport`: an rclpy node's transport, to reach graph nodes already running."""
    bag_path = resolve_bag(params)
    scenario = read_scenario(bag_path)
    output = output if output is not None else default_output(params, scenario.name)
    if output.exists():
        raise ParamsError(f"{output}: output folder exists already; choose another output")
    with open_rollouts(scenario, params, bag_path, transport) as rollouts:
        outcome = run_attack(scenario, params, progress=progress, rollouts=rollouts)
    return output, write_results(output, outcome, bag_path)


def summary(report: dict) -> dict:
    """What both ways print of a report when they finish: the scores of an attack found, or how
    close the search came and why nothing was found."""
    found = ("nds", "nds_t", "fn", "tp") if report["collision"] else ("closest_approach", "message")
    return {key: report[key] for key in ("scenario", "planner", "objective", "collision", *found, "rollouts")}
