"""One attack from validated params to a results folder: what `advperc attack` and the
orchestrator node both call, so both choose the same output folder, check it before any work,
run the same search and write the same report."""

import logging
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any

from tqdm import tqdm

from advperc_ros.backends.base import EXTERNAL, Rollouts
from advperc_ros.backends.embedded import Stack
from advperc_ros.backends.registry import open_rollouts
from advperc_ros.backends.resumed import Checkpoint, ResumedRollouts
from advperc_ros.configs import CoreConfigs, core_configs
from advperc_ros.core.rules.verdict import attacked_rule
from advperc_ros.core.scenario import Scenario
from advperc_ros.core.search.books import Estimate
from advperc_ros.core.search.config import SearchConfig, largest_budget, smallest_budget
from advperc_ros.core.search.diagnosis import inconclusive_search
from advperc_ros.core.search.pipeline import run_search
from advperc_ros.core.search.problem import AttackProblem
from advperc_ros.exceptions import GroundTruthFails, InconclusiveSearch, Interrupted, NodeGone, ParamsError
from advperc_ros.params import AttackParams, resolve_bag
from advperc_ros.results.destination import MIB, check_free_space, check_output, exclusive, full_disk_said
from advperc_ros.results.folder import write_results
from advperc_ros.results.outcome import AttackOutcome
from advperc_ros.ros.bag import read_scenario


class RolloutProgress:
    """The progress bar of a search, which draws what the search says after each rollout
    (`books.Estimate`: the rollouts run, the total it expects at most, the phase, the best so far) and,
    for a log that is not a terminal, prints a line per rollout; `close` ends the bar at the count."""

    def __init__(self, name: str, enabled: bool = True, say: Callable[[str], None] | None = None,
                 objective: str = "metric") -> None:
        self.name, self.objective = name, objective
        self.say = say  # a line per rollout, for a log that is not a terminal
        self.run = 0  # rollouts run so far (the bar's own count stays 0 when the bar is off)
        self.bar = tqdm(desc=name, unit="rollout", disable=not enabled, file=sys.stderr, mininterval=1.0)

    def __call__(self, estimate: Estimate) -> None:
        self.bar.total = estimate.total
        self.bar.set_description(f"{self.name} ({estimate.label})", refresh=False)
        postfix = {"best": "none yet" if estimate.best is None else f"{estimate.best:.4f}"}
        if estimate.inconclusive:  # a stack that fails shows at once, not only in the report
            postfix["inconclusive"] = str(estimate.inconclusive)
        self.bar.set_postfix(postfix, refresh=False)
        self.bar.update()
        self.run = estimate.run
        if self.say is not None:
            self.say(self.line(estimate))

    def line(self, estimate: Estimate) -> str:
        """The rollout just run, as a person reads it in a log (ros2 launch's): the count against the
        total the bar shows, its verdict, the best attack so far, the collisions found and, once one was,
        the rollouts left inconclusive."""
        row = estimate.row
        verdict = (f"inconclusive ({row.inconclusive})" if row.inconclusive
                   else "collision" if row.collided else "no collision")
        best = "no attack yet" if estimate.best is None else f"best {self.objective} {estimate.best:.4f}"
        unsure = f"; {estimate.inconclusive} inconclusive" if estimate.inconclusive else ""
        return (f"rollout {estimate.run} of about {estimate.total}: {verdict}; {best}; "
                f"{estimate.collisions} collision{'s' * (estimate.collisions != 1)} so far{unsure}")

    def close(self) -> None:
        self.bar.total = self.run
        self.bar.close()


def check_budget(params: AttackParams, scenario: Scenario) -> None:
    """Refuse a `search.budget` below the ground truth and one drop of each agent: such a search cannot
    try every agent once, and the guided method's first batch (all of them) did not fit it at all."""
    needed = smallest_budget(scenario.agents.shape[1])
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
    counter = RolloutProgress(scenario.name, progress, say, params.objective)
    rule = attacked_rule(params.rule.name, scenario, configs.rollout, configs.rulebook)
    problem = AttackProblem(scenario, backend.rollout, params.objective,
                            run_rollouts=getattr(backend, "rollout_many", None), kinds=config.errors.kinds,
                            attacked_rule=rule, restriction=params.restriction())
    try:
        result = run_search(problem, config, on_estimate=counter)
    finally:
        counter.close()
        if own is not None:  # this function's own stack: its worker pool ends here
            own.close()
    unsure = inconclusive_search(problem.log)
    if unsure is not None:
        raise InconclusiveSearch(unsure)
    recorded = backend.rollout(result.best.errors, record=True) if result.best is not None else None
    if recorded is not None and rule is not None:  # judged as the search judged it, to tell whether it reproduced
        recorded = rule.judge(recorded, problem.truth.rollout if problem.truth is not None else None)
    attacked = backend.attacked_planner
    if attacked.node is not None:
        params = replace(params, planner=EXTERNAL, planner_params={})
    return AttackOutcome(scenario=scenario, params=params, heuristic_best=result.heuristic, best=result.best,
                         recorded=recorded, log=problem.log, wall_time_s=time.perf_counter() - started,
                         planner_node=attacked.node, tracker_node=attacked.tracker_node,
                         planner_version=attacked.version, joint=result.joint,
                         approach=result.approach, ground_truth=problem.truth.rollout if problem.truth else None,
                         rollout_config=configs.rollout, rulebook=configs.rulebook)


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
    rollouts = largest_budget(search, agents)
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
                                     rollouts=ResumedRollouts(rollouts, checkpoint, scenario, configs.rollout))
            report = write_results(output, outcome, bag_path)
            finished = True
        except (InconclusiveSearch, GroundTruthFails):
            finished = True  # rollouts that found nothing out, or nothing to attack: not worth resuming
            raise
        except NodeGone as gone:
            raise NodeGone(f"{gone}; the checkpoint keeps every rollout done before it: once the node runs again, "
                           f"resume the attack (advperc attack {source} --resume {output}, or resume:=true)") from None
        except KeyboardInterrupt:
            raise Interrupted(f"finish it with: advperc attack {source} --resume {output}", output) from None
        finally:
            checkpoint.close(finished)
    return report


# whose INFO lines an attack shows: the backends' and the bundled planners' (ObP compiling its NLP, or why not)
SHOWN_LOGGERS = ("advperc_ros.backends", "advperc_ros.core.planners")


@contextmanager
def backend_log(handler: logging.Handler) -> Iterator[None]:
    """The backends' and planners' log lines through `handler` while an attack runs, from INFO up: the graph's
    line naming the planner it attacks (and the version it announced), a rollout it found inconclusive, ObP
    compiling its NLP once per machine. Python's logging has no handler of its own for them, and drops INFO
    lines."""
    loggers = [logging.getLogger(name) for name in SHOWN_LOGGERS]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)
    try:
        yield
    finally:
        for logger, level in zip(loggers, levels):
            logger.removeHandler(handler)
            logger.setLevel(level)


def summary(report: dict) -> dict:
    """What both ways print of a report when they finish: the scores of an attack found, or how
    close the search came and why nothing was found."""
    found = ("nds", "nds_t", "fn", "tp", "reproduced") if report["collision"] else ("closest_approach", "message")
    return {key: report[key] for key in ("scenario", "planner", "objective", "rule", "collision", *found, "rollouts",
                                         "inconclusive_rollouts")}
