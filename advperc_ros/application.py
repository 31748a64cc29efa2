"""One attack from validated params to a results folder: what `advperc attack` and the
orchestrator node both call, so both choose the same output folder, check it before any work,
run the same search and write the same report."""

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any

from tqdm import tqdm

from advperc_ros.backend import EXTERNAL, Rollouts, Stack
from advperc_ros.checkpoint import Checkpoint, ResumedRollouts
from advperc_ros.core.scenario import Scenario
from advperc_ros.core.search.pipeline import SearchConfig, budget, run_search
from advperc_ros.core.search.problem import AttackProblem, LogRow, Phase
from advperc_ros.core.search.random_search import RandomSearchConfig
from advperc_ros.exits import Interrupted
from advperc_ros.outcome import AttackOutcome
from advperc_ros.params import AttackParams, resolve_bag, rollout_config
from advperc_ros.paths import check_output
from advperc_ros.results import write_results
from advperc_ros.ros.bag import read_scenario


def search_config(params: AttackParams) -> SearchConfig:
    search = params.search
    return SearchConfig(
        heuristic_iterations=search.heuristic.iterations,
        random=RandomSearchConfig(steps=search.random.steps, proposals=search.random.proposals,
                                  max_offset=search.random.max_offset, yaw_std=search.random.yaw_std),
        refine_iterations=search.refine.iterations,
        seed=params.seed,
    )


@contextmanager
def open_rollouts(scenario: Scenario, params: AttackParams, bag_path: Path, transport: Any = None) -> Iterator[Rollouts]:
    """The backend `rollout_backend` names, ready to use and shut down on exit. `transport`
    (graph backend, nodes not spawned) lets an rclpy orchestrator reach nodes over its own node."""
    if params.rollout_backend != "graph":
        yield Stack(scenario, params)
        return
    from advperc_ros.graph.rollouts import GraphRollouts

    with GraphRollouts(scenario, params, bag_path, transport) as graph:
        yield graph


def run_attack(scenario: Scenario, params: AttackParams, progress: bool = True,
               rollouts: Rollouts | None = None) -> AttackOutcome:
    """The whole search over `rollouts` (default: embedded), then the best attack recorded."""
    started = time.perf_counter()
    backend = rollouts if rollouts is not None else Stack(scenario, params)
    config = search_config(params)
    bar = tqdm(total=budget(config, scenario.agents.shape[1]), desc=scenario.name, unit="rollout",
               disable=not progress, file=sys.stderr, mininterval=1.0)

    def on_rollout(row: LogRow) -> None:
        phase = "heuristic" if row.phase.heuristic else {Phase.RANDOM: "random search"}.get(row.phase, str(row.phase))
        bar.set_description(f"{scenario.name} ({phase})", refresh=False)
        bar.set_postfix(best=f"{row.best_metric:.4f}", refresh=False)
        bar.update()

    problem = AttackProblem(scenario, backend.rollout, params.objective, on_rollout=on_rollout)
    try:
        result = run_search(problem, config)
    finally:
        bar.close()
    recorded = backend.rollout(result.best.errors, record=True) if result.best is not None else None
    attacked = backend.attacked_planner
    if attacked.node is not None:
        params = replace(params, planner=EXTERNAL, planner_params={})
    return AttackOutcome(scenario=scenario, params=params, heuristic_best=result.heuristic, best=result.best,
                         recorded=recorded, log=problem.log, wall_time_s=time.perf_counter() - started,
                         planner_node=attacked.node)


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
                     transport: Any = None, resume: bool = False) -> tuple[Path, dict]:
    """Run the attack the params describe and write its results folder; (folder, report). Every
    rollout is checkpointed as it completes (advperc_ros.checkpoint); `resume` finishes an attack
    that was killed, with the report it would have written. `transport`: an rclpy node's
    transport, to reach graph nodes already running."""
    bag_path = resolve_bag(params)
    scenario = read_scenario(bag_path)
    output = output if output is not None else default_output(params, scenario.name)
    check_output(output)
    checkpoint = Checkpoint(output, params, resume)
    finished = False
    try:
        with open_rollouts(scenario, params, bag_path, transport) as rollouts:
            outcome = run_attack(scenario, params, progress=progress, rollouts=ResumedRollouts(
                rollouts, checkpoint, scenario.agents, rollout_config(params.flat())))
        report = write_results(output, outcome, bag_path)
        finished = True
    except KeyboardInterrupt:
        source = params.source or "PARAMS"
        raise Interrupted(f"finish it with: advperc attack {source} --resume {output}") from None
    finally:
        checkpoint.close(finished)
    return output, report


def summary(report: dict) -> dict:
    """What both ways print of a report when they finish: the scores of an attack found, or how
    close the search came and why nothing was found."""
    found = ("nds", "nds_t", "fn", "tp") if report["collision"] else ("closest_approach", "message")
    return {key: report[key] for key in ("scenario", "planner", "objective", "collision", *found, "rollouts")}
