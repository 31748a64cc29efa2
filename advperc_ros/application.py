"""One attack from validated params to a results folder: what `advperc attack` and the
orchestrator node both call, so both choose the same output folder, check it before any work,
run the same search and write the same report."""

import math
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from tqdm import tqdm

from advperc_ros.backends.base import EXTERNAL, Rollouts
from advperc_ros.backends.embedded import Stack
from advperc_ros.backends.registry import open_rollouts
from advperc_ros.backends.resumed import Checkpoint, ResumedRollouts
from advperc_ros.configs import CoreConfigs, core_configs
from advperc_ros.core.scenario import Scenario
from advperc_ros.core.search import phantom
from advperc_ros.core.search.config import SearchConfig, budget
from advperc_ros.core.search.diagnosis import inconclusive_search
from advperc_ros.core.search.method import Progress
from advperc_ros.core.search.pipeline import run_search
from advperc_ros.core.search.problem import AttackProblem, Evaluation, LogRow, Phase
from advperc_ros.core.search.refine import dropped_runs
from advperc_ros.core.search.registry import search_method
from advperc_ros.exceptions import GroundTruthFails, InconclusiveSearch, Interrupted, ParamsError
from advperc_ros.params import AttackParams, resolve_bag
from advperc_ros.results.destination import MIB, check_free_space, check_output, exclusive, full_disk_said
from advperc_ros.results.folder import write_results
from advperc_ros.results.outcome import AttackOutcome
from advperc_ros.ros.bag import read_scenario


class RolloutProgress:
    """The progress bar of a search, counting the rollouts that run. Its total is the rollouts run
    so far plus those still to come as far as the search has shown them: every agent's drop, the
    bisections (2 x iterations at most) of each agent whose drop collided, and once an agent is
    influential what the search method still owes (`SearchMethod.still_owed`: the paper's random
    steps and refine's bisections of the best attack's dropped runs; the guided method's share of
    the bound, and once its rounds begin the rest of its budget, which it spends), never past the
    budget; the joint drops, when no single drop collided, show one rollout at a time. The paper's
    bound would leave the bar at 12-39 %: most agents are not influential, and a bisection or a
    random step can end early; `close` ends the bar at the count."""

    def __init__(self, name: str, config: SearchConfig, num_agents: int, best: Callable[[], Evaluation | None],
                 enabled: bool = True, say: Callable[[str], None] | None = None, objective: str = "metric") -> None:
        self.name, self.config, self.num_agents, self.best = name, config, num_agents, best
        self.say, self.objective = say, objective  # a line per rollout, for a log that is not a terminal
        self.collisions = 0
        self.run = 0  # rollouts counted so far (the bar's own count stays 0 when the bar is off)
        self.total = 1 + num_agents  # the estimate the bar shows
        self.method = search_method(config)
        self.drops = self.influential = self.bisections = self.random = self.refined = self.refine_runs = 0
        self.phantoms = 0  # phantom obstacles run (ghosts on)
        self.bisections_owed = 0  # bisections run plus those the influential agents' drops still owe
        self.joint = False  # a joint drop has run
        self.approach = False  # the approach phase has run (no drop collided)
        self.began: int | None = None  # the rollouts run before the method's own phases began
        self.bar = tqdm(total=1 + num_agents, desc=name, unit="rollout", disable=not enabled, file=sys.stderr,
                        mininterval=1.0)

    def __call__(self, row: LogRow) -> None:
        phase = row.phase
        if phase == Phase.HEURISTIC_DROP:
            self.drops += 1
            if not self.method.batched_heuristic:  # it bisects an agent before dropping the next: those are done
                self.bisections_owed = self.bisections
            self.bisections_owed += 2 * self.config.heuristic_iterations * row.collided  # batched: after all drops
            self.influential += row.collided
        elif phase == Phase.PHANTOM:  # ghosts are on: the phantom obstacles run after the drops
            self.phantoms += 1
            self.influential += row.collided
        elif phase == Phase.JOINT:  # no single drop collided: the joint drops run, within their own bound
            self.joint = True
            self.influential += row.collided
        elif phase == Phase.APPROACH:  # no drop collided: the approach phase runs, within its own bound
            self.joint = self.approach = True
            self.influential += row.collided
        elif phase in (Phase.HEURISTIC_START, Phase.HEURISTIC_END):
            self.bisections += 1
        elif phase == Phase.RANDOM:
            self.random += 1
        elif phase == Phase.REFINE:
            self.refined += 1
        best = self.best()
        if phase != Phase.REFINE and best is not None:  # refine bisects the runs of the best before it
            self.refine_runs = len(dropped_runs(best.errors.fn[: best.rollout.num_frames]))
        self.total = self.bar.total = self.run + 1 + self._still_to_run(phase)
        name = "heuristic" if phase.heuristic else self.method.phases.get(phase, str(phase))
        self.bar.set_description(f"{self.name} ({name})", refresh=False)
        self.bar.set_postfix(best="none yet" if best is None else f"{best.metric:.4f}", refresh=False)
        self.bar.update()
        self.run += 1
        self.collisions += row.collided and not row.inconclusive
        if self.say is not None:
            self.say(self.line(row))

    def line(self, row: LogRow) -> str:
        """The rollout just run, as a person reads it in a log (ros2 launch's): the count against the
        total the bar shows, its verdict, the best attack so far and the collisions found."""
        verdict = (f"inconclusive ({row.inconclusive})" if row.inconclusive
                   else "collision" if row.collided else "no collision")
        best = "no attack yet" if math.isnan(row.best_metric) else f"best {self.objective} {row.best_metric:.4f}"
        return (f"rollout {self.run} of about {self.total}: {verdict}; {best}; "
                f"{self.collisions} collision{'s' * (self.collisions != 1)} so far")

    def _still_to_run(self, phase: Phase) -> int:
        left = budget(self.config, self.num_agents, self.joint, self.approach) - self.run - 1
        if phase in self.method.phases:
            if self.began is None:
                self.began = self.run
            return min(left, self.method.still_owed(phase, self._progress()))
        bisections = max(0, self.bisections_owed - self.bisections)
        tail = self.method.still_owed(None, self._progress()) if self.influential else 0
        phantoms = phantom.worst_case(self.config.errors) - self.phantoms
        return min(left, self.num_agents - self.drops + phantoms + bisections + tail)

    def _progress(self) -> Progress:
        return Progress(run=self.run, began=self.began, random=self.random, refined=self.refined,
                        refine_runs=self.refine_runs)

    def close(self) -> None:
        self.bar.total = self.run
        self.bar.close()


def check_budget(params: AttackParams, scenario: Scenario) -> None:
    """Refuse a `search.budget` below the ground truth and one drop of each agent: such a search cannot
    try every agent once, and the guided method's first batch (all of them) did not fit it at all."""
    needed = 1 + scenario.agents.shape[1]
    if 0 < params.search.budget < needed:
        raise ParamsError(f"{params.source or 'params'}: parameter 'search.budget' is {params.search.budget}, below the "
                          f"{needed} rollouts that try each of the scenario's {needed - 1} agents once (and the ground "
                          "truth): give at least that, or 0 for the default")


def run_attack(scenario: Scenario, params: AttackParams, progress: bool = True,
               rollouts: Rollouts | None = None, configs: CoreConfigs | None = None,
               say: Callable[[str], None] | None = None) -> AttackOutcome:
    """The whole search over `rollouts` (default: embedded), then the best attack recorded.
    `configs`: the params' core configs, when the caller built them; `say`: where a line per rollout
    goes (a node's logger), besides or instead of the progress bar."""
    started = time.perf_counter()
    check_budget(params, scenario)
    configs = configs if configs is not None else core_configs(params)
    own: Stack | None = None
    backend: Rollouts
    if rollouts is None:
        backend = own = Stack(scenario, configs)
    else:
        backend = rollouts
    config = configs.search
    problem: AttackProblem | None = None

    def best() -> Evaluation | None:
        return problem.best if problem is not None else None

    counter = RolloutProgress(scenario.name, config, scenario.agents.shape[1], best, progress, say, params.objective)
    problem = AttackProblem(scenario, backend.rollout, params.objective, on_rollout=counter,
                            run_rollouts=getattr(backend, "rollout_many", None), kinds=config.errors.kinds)
    try:
        result = run_search(problem, config)
    finally:
        counter.close()
        if own is not None:  # this function's own stack: its worker pool ends here
            own.close()
    unsure = inconclusive_search(problem.log)
    if unsure is not None:
        raise InconclusiveSearch(unsure)
    recorded = backend.rollout(result.best.errors, record=True) if result.best is not None else None
    attacked = backend.attacked_planner
    if attacked.node is not None:
        params = replace(params, planner=EXTERNAL, planner_params={})
    return AttackOutcome(scenario=scenario, params=params, heuristic_best=result.heuristic, best=result.best,
                         recorded=recorded, log=problem.log, wall_time_s=time.perf_counter() - started,
                         planner_node=attacked.node, tracker_node=attacked.tracker_node,
                         planner_version=attacked.version, joint=result.joint,
                         approach=result.approach)


def default_output(params: AttackParams, scenario_name: str) -> Path:
    """results/<params file name, else scenario>-seed<N>, numbered on when taken."""
    stem = params.source.stem if params.source is not None else scenario_name
    base = Path("results") / f"{stem}-seed{params.seed}"
    candidate, n = base, 1
    while candidate.exists():
        n += 1
        candidate = base.with_name(f"{base.name}-{n}")
    return candidate


CHECKPOINT_BYTES_PER_NUMBER = 25  # a float's repr and its separator in a checkpoint line, rounded up
CHECKPOINT_BYTES_PER_ABSENCE = 6  # `null, `: the distance to an agent absent at that frame
RESULTS_PER_BAG_BYTE = 8  # results folder / ground-truth bag: its layers' bags (4.3 measured, more under a profile)
PLOTS_BYTES = 4 * MIB  # the plots, the animation and the reports, whatever the bag


def output_bytes(scenario: Scenario, search: SearchConfig, bag_path: Path) -> int:
    """A generous estimate of the disk an attack uses: its checkpoint (a line per rollout of the
    search's bound: the ego and each agent's distance per frame) and its results folder."""
    frames, agents = scenario.agents.shape
    rollouts = budget(search, agents, joint=True, approach=True)
    present = int(scenario.agents.valid.sum())
    line = (4 * frames + present) * CHECKPOINT_BYTES_PER_NUMBER + (frames * agents - present) * CHECKPOINT_BYTES_PER_ABSENCE
    bag = sum(part.stat().st_size for part in Path(bag_path).rglob("*") if part.is_file()) if Path(bag_path).is_dir() \
        else Path(bag_path).stat().st_size
    return rollouts * line + RESULTS_PER_BAG_BYTE * bag + PLOTS_BYTES


def output_lock(output: Path) -> Path:
    """The file an attack holds beside its output while it runs: a second attack on that output would
    resume the checkpoint the first is still writing, or delete it to start afresh."""
    return output.parent / f".{output.name}.lock"


def attack_to_folder(params: AttackParams, output: Path | None, progress: bool = False,
                     transport: Any = None, resume: bool = False,
                     say: Callable[[str], None] | None = None, bag_path: Path | None = None) -> tuple[Path, dict]:
    """Run the attack the params describe and write its results folder; (folder, report). Every
    rollout is checkpointed as it completes (advperc_ros.backends.resumed); `resume` finishes an attack
    that was killed, with the report it would have written. The output is locked first, before
    anything is made or removed, so only one attack at a time has it. `transport`: an rclpy node's
    transport, to reach graph nodes already running. `bag_path`: where the bag the params name is
    when it is not where they name it (a campaign's Ray worker holds a copy of its own, and the
    params, their `bag` in the report and config hash included, stay the campaign's)."""
    bag_path = bag_path if bag_path is not None else resolve_bag(params)
    scenario = read_scenario(bag_path)
    output = output if output is not None else default_output(params, scenario.name)
    check_output(output)
    configs = core_configs(params)  # once, for the backend, the checkpoint and the search
    check_free_space(output, output_bytes(scenario, configs.search, bag_path))
    output.parent.mkdir(parents=True, exist_ok=True)  # where the lock goes
    with exclusive(output_lock(output), f"{output}: another attack is running on this output; let it finish or "
                                        "stop it first"):
        check_output(output)  # again: an attack that held the lock until now may have finished into it
        return output, _checkpointed_attack(params, scenario, bag_path, output, progress, transport, resume, configs,
                                            say)


def _checkpointed_attack(params: AttackParams, scenario: Scenario, bag_path: Path, output: Path, progress: bool,
                         transport: Any, resume: bool, configs: CoreConfigs, say: Callable[[str], None] | None) -> dict:
    """The attack with its checkpoint, its report written into `output`; the caller holds the output's
    lock. A disk that fills on the way ends it in one line, the checkpoint kept for --resume."""
    source = params.source or "PARAMS"
    checkpoint = Checkpoint(output, configs.canonical, scenario, resume)
    finished = False
    with full_disk_said(output, f"the checkpoint keeps every rollout done; free some space, then: advperc attack {source} "
                                f"--resume {output}"):
        try:
            with open_rollouts(scenario, configs, bag_path, transport) as rollouts:
                outcome = run_attack(scenario, params, progress=progress, configs=configs, say=say,
                                     rollouts=ResumedRollouts(rollouts, checkpoint, scenario.agents, configs.rollout))
            report = write_results(output, outcome, bag_path)
            finished = True
        except (InconclusiveSearch, GroundTruthFails):
            finished = True  # rollouts that found nothing out, or nothing to attack: not worth resuming
            raise
        except KeyboardInterrupt:
            raise Interrupted(f"finish it with: advperc attack {source} --resume {output}", output) from None
        finally:
            checkpoint.close(finished)
    return report


def summary(report: dict) -> dict:
    """What both ways print of a report when they finish: the scores of an attack found, or how
    close the search came and why nothing was found."""
    found = ("nds", "nds_t", "fn", "tp", "reproduced") if report["collision"] else ("closest_approach", "message")
    return {key: report[key] for key in ("scenario", "planner", "objective", "collision", *found, "rollouts")}
