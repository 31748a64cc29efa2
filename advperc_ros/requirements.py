"""`advperc requirements`: how good perception must be for a planner, per error kind and distance from the ego.

For each scenario, error kind and distance bin, a bisection on the kind's magnitude: at each magnitude the
attack's own search runs with its errors restricted to that kind, to the cars in that bin, and bounded by
that magnitude (`requirement.*` params, `core.perception_errors.restriction`). A search that breaks the rule
brings the upper end down, and its results folder (bag, report) is the attack that breaks the bound; one
that finds nothing within its budget brings the lower end up. The bracket [tolerated, breaks_at] is what a
perception team and a planning team can agree on, with the bag that shows why.

A tolerated level is what this search could not break, an upper bound on what is safe, not a proof: a
stronger search, a larger budget or another seed may break it. The rows and the Markdown say so.

Every search is a cell of the campaign executors (serial, a process pool, Ray), written into
`<output>/searches/<cell>/` as an attack's results folder; a run killed at any point is resumed by running
the same command again (finished searches are read back, and the bisection takes the same steps).
"""

import itertools
import json
import math
import os
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from advperc_ros.campaign.execute import make_executor
from advperc_ros.campaign.run import clear_staging
from advperc_ros.campaign.spec import ATTACK, Cell, load_campaign, plan
from advperc_ros.core.perception_errors import parse_error_kinds
from advperc_ros.core.perception_errors.restriction import MAGNITUDES
from advperc_ros.exceptions import OutputError, ParamsError, RequirementSearchFailed
from advperc_ros.exits import EXIT_NOTHING_TO_ATTACK
from advperc_ros.params import AttackParams, load_params, read_yaml, resolve_bag
from advperc_ros.results.destination import check_output, exclusive
from advperc_ros.ros.bag import read_scenario

REQUIREMENTS_JSON, REQUIREMENTS_MD, NOISE_YAML, REQUEST_JSON = (
    "requirements.json", "requirements.md", "noise.yaml", ".requirements-request.json")
SEARCHES = "searches"  # the folder of the bisection's searches, one results folder each
LOCK = ".requirements.lock"  # held while a run writes the folder: a second run would start the same searches
CAVEAT = ("A tolerated level is the largest magnitude at which this search, within its budget, found no violation: "
          "an upper bound on what is safe (a stronger search may break it), not a proof of safety.")


@dataclass(frozen=True)
class Request:
    """What a requirements run was asked: the scenarios' params, the kinds, the bins (outer radii, m) and the
    bisection's halvings. A resumed run must ask the same, so its finished searches are this run's."""

    params: tuple[str, ...]
    kinds: tuple[str, ...]
    radii: tuple[float, ...]
    iterations: int


@dataclass(frozen=True)
class Bracket:
    """One row of requirements.json: of one scenario, kind and bin, the largest magnitude searched without a
    violation and the smallest with one, and that search's results folder."""

    scenario: str
    kind: str
    unit: str
    near: float
    far: float
    tolerated: float  # no violation found at this magnitude (0: perfect perception, the ground truth's)
    breaks_at: float | None  # a violation found at this magnitude; None: none up to the kind's largest
    attack: str | None  # the results folder of the search that broke it, in the output folder
    rule: str
    rollouts: int  # of every search of this bracket
    searches: int
    typical_samples: int = 0  # typical errors (the PEM's samples) within the requirement at the tolerated level
    typical_violations: int = 0  # of them, rollouts that broke the row's rule or were inconclusive
    # the search's refusal when perfect perception already breaks the rule: nothing is tolerated (tolerated and
    # breaks_at 0, no attack); the scenario's other rows say the same, the other scenarios' are bracketed
    ground_truth_breaks: str | None = None

    @property
    def bin(self) -> str:
        return f"{self.near:g}-{self.far:g} m"

    def line(self) -> str:
        """The row in a line, as the command prints it."""
        if self.ground_truth_breaks is not None:
            return f"{self.scenario} {self.kind} {self.bin}: nothing tolerated, {self.ground_truth_breaks}"
        breaks = "not broken" if self.breaks_at is None else f"breaks at {self.breaks_at:.3g} {self.unit} ({self.attack})"
        missed = (f"; yet {self.typical_violations} of {self.typical_samples} typical errors within it break the rule"
                  if self.typical_violations else "")
        return f"{self.scenario} {self.kind} {self.bin}: tolerated up to {self.tolerated:.3g} {self.unit}, {breaks}{missed}"


def check_request(params: Sequence[AttackParams], kinds: Sequence[str], radii: Sequence[float], iterations: int,
                  typical: int = 0, where: str = "advperc requirements") -> None:
    """Every argument checked before any search: a ParamsError naming the argument."""
    if typical < 0:
        raise ParamsError(f"{where}: --typical must be a number of samples >= 0, got {typical}")
    for kind in kinds:
        if kind not in MAGNITUDES:
            raise ParamsError(f"{where}: --kinds has {kind!r}: a requirement bounds one of {', '.join(MAGNITUDES)}")
    if len(set(kinds)) != len(kinds) or not kinds:
        raise ParamsError(f"{where}: --kinds must name each kind once, at least one")
    if not radii or any(not (math.isfinite(r) and r > 0) for r in radii) or list(radii) != sorted(set(radii)):
        raise ParamsError(f"{where}: --bins must be increasing positive radii in m (as 20,40,60), got "
                          f"{','.join(f'{r:g}' for r in radii)}")
    if not 0 <= iterations <= 20:
        raise ParamsError(f"{where}: --iterations must be from 0 to 20, got {iterations}")
    for p in params:
        if p.requirement.kind:
            raise ParamsError(f"{p.source or 'params'}: parameter 'requirement.kind' is set; advperc requirements "
                              f"sets it for each search")


def requirements_of(paths: Sequence[str], output: Path, kinds: str, radii: Sequence[float], iterations: int,
                    budget: int | None, executor: str, workers: int, progress: bool, typical: int = 0) -> list[Bracket]:
    """The command's work: every params file and argument checked before any search (`kinds`: a comma-separated
    list, or all), then `run_requirements`."""
    chosen = tuple(MAGNITUDES) if kinds == "all" else tuple(kind.strip() for kind in kinds.split(","))
    named = [entry for path in paths for entry in _systems(Path(path))]
    names, params = [name for name, _ in named], [p for _, p in named]
    if budget is not None:
        params = [p.with_values(**{"search.budget": budget}) for p in params]
    check_request(params, chosen, radii, iterations, typical)
    if len(set(names)) != len(names):
        twice = next(name for name in names if names.count(name) > 1)
        raise ParamsError(f"advperc requirements: {twice!r} is named twice (two params files of one scenario, or a "
                          "campaign cell and a params file): one each")
    request = Request(tuple(str(Path(path).resolve()) for path in paths), chosen, tuple(radii), iterations)
    brackets = run_requirements(list(zip(names, params)), output, request, executor, workers, progress)
    if typical:
        by_name = dict(zip(names, params))
        brackets = [bracket if bracket.ground_truth_breaks else with_typical(bracket, by_name[bracket.scenario], typical)
                    for bracket in brackets]
        write_requirements(output, brackets)
    return brackets


def _systems(path: Path) -> list[tuple[str, AttackParams]]:
    """(name, params) of each system a path names: a params file's scenario (named as the scenario), or every
    attack cell of a campaign file (its scenarios x objectives x seeds x rules x planners, named as its cells)."""
    document = read_yaml(path, "params or campaign file")
    if isinstance(document, dict) and "scenarios" in document:
        return [(cell.name, cell.params) for cell in plan(load_campaign(path)) if cell.role == ATTACK]
    params = load_params(path)
    return [(read_scenario(resolve_bag(params)).name, params)]


def with_typical(bracket: Bracket, base: AttackParams, samples: int) -> Bracket:
    """The statistical side of a tolerated level: `samples` typical errors (the shipped perception error model's
    samples, as `advperc check-typical` rolls them out), each projected onto the requirement at its tolerated
    level, rolled out: how often a detector with typical errors, bounded as the requirement says, breaks the rule."""
    from dataclasses import replace

    import numpy as np

    from advperc_ros.backends.embedded import Stack
    from advperc_ros.configs import core_configs
    from advperc_ros.core.pem import default_pem
    from advperc_ros.core.perception_errors import PerceptionErrors
    from advperc_ros.core.perception_errors.restriction import Scene
    from advperc_ros.core.rollout import RolloutResult, true_agents
    from advperc_ros.core.rules.verdict import attacked_rule
    from advperc_ros.core.typical import check_typical

    params = search_params(base, bracket.kind, bracket.near, bracket.far, bracket.tolerated)
    restriction, configs = params.restriction(), core_configs(params)
    assert restriction is not None  # search_params sets it
    scenario = read_scenario(resolve_bag(params))
    stack = Stack(scenario, configs)
    try:
        truth = stack.rollout(PerceptionErrors.none(*scenario.agents.shape))
        boxes = true_agents(truth, scenario)
        scene = Scene.of(boxes.x, boxes.y, boxes.yaw, scenario.agents.valid, truth.ego_xy, scenario.dt,
                         restriction.near, restriction.far)
        rule = attacked_rule(params.rule.name, scenario, configs.rollout, configs.rulebook)

        def judged(errors: PerceptionErrors) -> RolloutResult:
            """The rollout of `errors` within the requirement, its verdict the row's rule's (as the search's)."""
            result = stack.rollout(restriction.project(errors, scene))
            return result if rule is None else rule.judge(result, truth)

        check = check_typical(scenario, judged, default_pem(configs.search.errors.kinds), samples,
                              np.random.default_rng(params.seed))
    finally:
        stack.close()
    return replace(bracket, typical_samples=check.samples, typical_violations=check.collisions + check.inconclusive)


def search_params(base: AttackParams, kind: str, near: float, far: float, magnitude: float) -> AttackParams:
    """The params of one search: `base` restricted to `kind` on the cars within [near, far) m, at most `magnitude`
    (the kind turned on among the error kinds if it is not one of the paper's)."""
    kinds = parse_error_kinds(base.errors.kinds)
    changes: dict = {"requirement.kind": kind, "requirement.magnitude": float(magnitude),
                     "requirement.near": float(near), "requirement.far": float(far), "search.method": "guided"}
    if kind not in kinds:
        changes["errors.kinds"] = ",".join(k for k in (*kinds, kind) if k not in ("position", "yaw", "drop"))
    return base.with_values(**changes)


@dataclass
class Bisection:
    """The bracket of one scenario, kind and bin as its searches come in: first the kind's largest magnitude,
    then halvings of [tolerated, breaks_at] while a violation has been found."""

    scenario: str
    base: AttackParams
    kind: str
    near: float
    far: float
    iterations: int
    low: float = 0.0
    high: float | None = None  # a magnitude found to break the rule
    attack: str | None = None
    rollouts: int = 0
    searches: int = 0
    refusal: str | None = None  # the search's line when the ground truth already breaks the rule

    def next_magnitude(self) -> float | None:
        """The magnitude to search next, None when the bracket is done."""
        if self.searches == 0:
            return MAGNITUDES[self.kind].largest
        if self.refusal is not None or self.high is None or self.searches > self.iterations:
            return None
        return (self.low + self.high) / 2.0

    def cell(self, magnitude: float) -> Cell:
        params = search_params(self.base, self.kind, self.near, self.far, magnitude)
        name = f"{self.scenario}-{self.kind}-{self.near:g}-{self.far:g}m-{magnitude:.6g}"
        return Cell(name, self.scenario, params.objective, params.seed, params.planner, params.canonical(),
                    params.source)

    def take(self, magnitude: float, report: dict, folder: Path) -> None:
        """A search's report: a violation brings the upper end down, none the lower end up."""
        self.searches += 1
        self.rollouts += int(report["rollouts"])
        if report["collision"]:
            self.high, self.attack = magnitude, f"{SEARCHES}/{folder.name}"
        else:
            self.low = magnitude

    def refuse(self, line: str) -> None:
        """The search was refused: perfect perception already breaks the rule, so no magnitude is tolerated."""
        self.searches += 1
        self.low, self.high, self.refusal = 0.0, 0.0, line

    def bracket(self) -> Bracket:
        unit = MAGNITUDES[self.kind].unit
        return Bracket(self.scenario, self.kind, unit, self.near, self.far, self.low, self.high, self.attack,
                       self.base.rule.name, self.rollouts, self.searches, ground_truth_breaks=self.refusal)


def _own_output(output: Path, request: Request) -> None:
    """Refuse an output folder that is not new, empty, or this very request's (to resume)."""
    if not output.exists():
        check_output(output)
        return
    if not output.is_dir():
        raise OutputError(f"{output}: the output is not a folder")
    found = sorted(entry.name for entry in output.iterdir() if entry.name != LOCK)
    if not found:
        return
    try:
        earlier = json.loads((output / REQUEST_JSON).read_text())
    except (OSError, ValueError):
        raise OutputError(f"{output}: a folder that no requirements run made (it holds {found[0]!r}): choose a new "
                          "or empty folder") from None
    if earlier != json.loads(json.dumps(asdict(request))):
        raise OutputError(f"{output}: holds a requirements run of other arguments ({REQUEST_JSON}): choose a new "
                          "folder, or repeat that run's arguments to resume it")


def run_requirements(scenarios: Sequence[tuple[str, AttackParams]], output: Path, request: Request, executor: str,
                     workers: int, progress: bool = False) -> list[Bracket]:
    """Every bracket of every scenario, kind and bin; the searches of one round run at once on the executor."""
    _own_output(output, request)
    output.mkdir(parents=True, exist_ok=True)
    with exclusive(output / LOCK, f"{output}: another requirements run is using this folder; let it finish first"):
        return _bisect(scenarios, output, request, executor, workers, progress)


def _bisect(scenarios: Sequence[tuple[str, AttackParams]], output: Path, request: Request, executor: str, workers: int,
            progress: bool) -> list[Bracket]:
    """`run_requirements` in its output folder, which it holds."""
    searches = output / SEARCHES
    searches.mkdir(parents=True, exist_ok=True)
    clear_staging(searches)  # what a killed search left half-written; its checkpoint stays, to resume from
    (output / REQUEST_JSON).write_text(json.dumps(asdict(request), indent=2) + "\n")
    bounds = [0.0, *request.radii]
    states = [Bisection(name, params, kind, near, far, request.iterations) for name, params in scenarios
              for kind in request.kinds for near, far in itertools.pairwise(bounds)]
    pool = make_executor(executor, searches, progress, workers)
    try:
        while True:
            round_ = [(state, m, state.cell(m)) for state in states if (m := state.next_magnitude()) is not None]
            if not round_:
                break
            todo = [cell for _, _, cell in round_ if _finished(searches, cell) is None]
            for cell in todo:
                pool.submit(cell)
            failed: list[tuple[str, str, int | None]] = []
            refused: dict[str, str] = {}  # by search: its line, where perfect perception already breaks the rule
            for _ in todo:
                result = pool.next_done()
                if result.error is not None and result.exit_code == EXIT_NOTHING_TO_ATTACK:
                    refused[result.name] = result.error.strip().splitlines()[-1]
                elif result.error is not None:
                    failed.append((result.name, result.error, result.exit_code))
            if failed:
                name, error, exit_code = min(failed)  # the same one whichever finished first
                raise RequirementSearchFailed(f"{searches / name}: {error.strip().splitlines()[-1]}", exit_code)
            for state, magnitude, cell in round_:
                if cell.name in refused:
                    state.refuse(refused[cell.name])
                else:
                    state.take(magnitude, cell.report(searches) or {}, searches / cell.name)
            write_requirements(output, [state.bracket() for state in states])
    finally:
        pool.close()
    brackets = [state.bracket() for state in states]
    write_requirements(output, brackets)
    return brackets


def _finished(searches: Path, cell: Cell) -> dict | None:
    """A search's report when it is finished, refused when it ran with other params (the params file changed
    since: its bracket would mix two configurations)."""
    report = cell.report(searches)
    if report is not None and report["config_hash"] != cell.params.config_hash():
        raise OutputError(f"{searches / cell.name}: finished with other params (config hash {report['config_hash']}); "
                          "remove it, or choose another output")
    return report


def markdown(brackets: Sequence[Bracket]) -> str:
    lines = ["# Perception requirements", "", CAVEAT, "",
             "| scenario | kind | bin | tolerated up to | breaks at | rule | searches | rollouts | attack | typical errors "
             "at the tolerated level |", "|---|---|---|---|---|---|---|---|---|---|"]
    for b in brackets:
        breaks = f"{b.breaks_at:.3g} {b.unit}" if b.breaks_at is not None else f"not up to {b.tolerated:.3g} {b.unit}"
        if b.ground_truth_breaks is not None:
            breaks = f"0 {b.unit}: perfect perception already breaks it"
        attack = b.attack or ""
        typical = f"{b.typical_violations} of {b.typical_samples} break it" if b.typical_samples else ""
        if b.typical_violations:  # errors inside the level that break the rule: the level is not tolerated
            typical += " (the search missed them: not tolerated)"
        lines.append(f"| {b.scenario} | {b.kind} | {b.bin} | {b.tolerated:.3g} {b.unit} | {breaks} | {b.rule} | "
                     f"{b.searches} | {b.rollouts} | {attack} | {typical} |")
    return "\n".join(lines) + "\n"


def noise_parameters(brackets: Sequence[Bracket]) -> str:
    """A scenario_simulator_v2 detection noise (model version 2) file at the tolerated levels, the tightest
    over the scenarios: per bin (`ellipse_y_radii`, circular: `ellipse_normalized_x_radius` 1), a position
    and a heading error whose standard deviation puts three of them at the tolerated level. The other kinds
    have no parameter of that model, and a scenario whose ground truth already breaks the rule says nothing of
    perception's."""
    radii = sorted({b.far for b in brackets})
    def tightest(kind: str) -> list[float] | None:
        rows = [b for b in brackets if b.kind == kind and b.ground_truth_breaks is None]
        if not rows:
            return None
        return [min(b.tolerated for b in rows if b.far == far) / 3.0 for far in radii]

    lines = ["# perception noise at the tolerated levels of `advperc requirements` (scenario_simulator_v2,",
             "# noise.model.version 2): a standard deviation a third of the tolerated error; " + CAVEAT,
             "noise:", "  model:", "    version: 2", "  v2:", f"    ellipse_y_radii: [{', '.join(f'{r:g}' for r in radii)}]"]
    for kind, name in (("position", "distance"), ("yaw", "yaw")):
        values = tightest(kind)
        if values is None:
            continue
        lines += [f"    {name}:", "      mean:", "        ellipse_normalized_x_radius: 1.0",
                  f"        values: [{', '.join('0.0' for _ in radii)}]", "      standard_deviation:",
                  "        ellipse_normalized_x_radius: 1.0", f"        values: [{', '.join(f'{v:.4g}' for v in values)}]"]
    return "\n".join(lines) + "\n"


def write_requirements(output: Path, brackets: Sequence[Bracket]) -> None:
    """requirements.json, requirements.md, noise.yaml and a plot per kind, each replaced at once."""
    from advperc_ros.results import plots

    rows = [{**asdict(b), "bin": b.bin, "caveat": CAVEAT} for b in brackets]
    for name, text in ((REQUIREMENTS_JSON, json.dumps(rows, indent=2) + "\n"), (REQUIREMENTS_MD, markdown(brackets)),
                       (NOISE_YAML, noise_parameters(brackets))):
        staging = output / f".{name}.partial"
        staging.write_text(text)
        os.replace(staging, output / name)
    for kind in dict.fromkeys(b.kind for b in brackets):
        plots.requirements(output / f"requirements-{kind}.png", [b for b in brackets if b.kind == kind])

