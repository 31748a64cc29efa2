"""The campaign file and its cells.

A campaign file is one YAML mapping (its fields: `FIELDS`, documented in the README's "Campaigns").
It is checked whole before any work: every field, every cell's params, every bag and planner; an
error is one ParamsError naming the file and the field. Cells are named from what they vary,
`<scenario>-<objective>-<seed>-<planner>`, then `-<rule>` when the rule attacked is not the default
collision (a replay: `<attack folder>-on-<planner>`), and a cell is finished when its folder holds its
report (results are renamed into place when complete).

A campaign of several planners also replays every attack it finds on each of the other planners (its
transfer cells, `<attack cell>-on-<planner>`, known only once the attack is), and a campaign with a
`baseline` (an earlier run's output) replays each attack the baseline found on this campaign's version of
the same cell (`<cell>-baseline`): attacks that travel between planners, and between versions of one.
"""

import json
import os
import re
import socket
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib.util import find_spec
from pathlib import Path
from typing import Any

from advperc_ros.backends.embedded import Stack
from advperc_ros.configs import core_configs
from advperc_ros.core.rules.registry import RULES
from advperc_ros.core.rules.verdict import DEFAULT_RULE
from advperc_ros.core.search.problem import OBJECTIVES
from advperc_ros.exceptions import OutputError, ParamsError, PluginError
from advperc_ros.exits import INPUT_ERRORS
from advperc_ros.params import (
    EXECUTION,
    PLANNER_PARAMS,
    AttackParams,
    find_bag,
    load_params,
    params_from_values,
    read_yaml,
    resolve_bag,
)
from advperc_ros.replay import REPLAY_JSON, load_attack
from advperc_ros.results.destination import check_output
from advperc_ros.results.folder import ERRORS, REPORT_JSON
from advperc_ros.ros.bag import read_scenario

EXECUTORS = ("process", "ray", "serial")
FINISHED_FIELDS = ("config_hash", "collision")  # what a resume reads of a finished cell's report before the summary
RAY_CLIENT = "ray://"  # a Ray Client address, from outside the cluster
RAY_CURRENT_CLUSTER = Path("/tmp/ray/ray_current_cluster")  # where `ray start` writes its address (Ray's `auto`)
RAY_REACH_TIMEOUT = 3.0  # s for a cluster's port to answer before the campaign refuses it
HOST = re.compile(r"[A-Za-z0-9][A-Za-z0-9.-]*|[0-9A-Fa-f:]+")  # a host name, IPv4 or IPv6 address
# the values each objective's metric can take: NDS and NDS-t are scores in [0, 1]; PEM LL is a mean log
# density, any finite number
THRESHOLD_RANGES = {"nds": (0.0, 1.0), "nds_t": (0.0, 1.0), "pem_ll": (-sys.float_info.max, sys.float_info.max)}
FIELDS = {
    "name": "campaign name: JUnit suite and default output folder (default: the file's name)",
    "output": "folder of the cell folders and the summary (default results/campaign-<name>)",
    "scenarios": "params files or ground-truth bag folders to attack (required unless replay)",
    "objectives": "objectives to search for (default: each params file's own)",
    "seeds": "seeds of the search's random draws (default: each params file's own)",
    "rules": "driving rules to attack (default: each params file's own rule.name)",
    "planners": "planners to attack, each {name, planner, planner_params} (default: each scenario's own)",
    "overrides": "parameters set in every cell, by dotted name (search.random.steps: 4)",
    "executor": "process (a pool of workers), ray, or serial (in this process)",
    "workers": "cells run at once (default: the CPUs of this machine)",
    "ray_address": "for executor ray: a running cluster's address (default: a local Ray on 127.0.0.1)",
    "thresholds": "per objective, the metric at which an attack found fails its JUnit test case",
    "replay": "a folder of attack results folders (another campaign's output): replay each on the planners",
    "baseline": "an earlier run's output of this campaign (the last planner version): its attacks replayed on this one",
}
# what a cell does: attack; or replay an attack (a replay campaign's, one found on another planner of this
# campaign, or one the baseline found on this cell's planner)
ATTACK, REPLAY, TRANSFER, BASELINE = "attack", "replay", "transfer", "baseline"
BASELINE_SUFFIX = "-baseline"  # a baseline cell's name: the cell whose baseline attack it replays, and this
ENTRY_FIELDS = ("name", "planner", "planner_params")
RULE = "rule.name"  # the parameter the `rules` axis sets
SUMMARY_JSON = "summary.json"  # a campaign's summary, every cell's row: what a baseline is read from
AXES = ("bag", "objective", "seed", RULE, "planner", PLANNER_PARAMS)  # what cells vary: not for `overrides`
STACK_AXES = ("objective", "seed", RULE)  # what cells vary that neither reads the bag nor builds the planner
LABEL = re.compile(r"[A-Za-z0-9_+][A-Za-z0-9_.+-]*")  # a cell name's parts: a folder name, never hidden


@dataclass(frozen=True)
class PlannerEntry:
    """A planner to attack. `planner` None keeps the scenario's own; `planner_params` are merged over
    the scenario's when the planner is its own, and replace them when it is another."""

    name: str
    planner: str | None = None
    planner_params: Mapping[str, Any] | None = None

    def apply(self, params: AttackParams) -> AttackParams:
        planner = self.planner or params.planner
        base = dict(params.planner_params) if planner == params.planner else {}
        return params.with_values(planner=planner, planner_params={**base, **(self.planner_params or {})})


@dataclass(frozen=True)
class Campaign:
    """A campaign file, checked whole before any cell runs: its cells are the product of scenarios,
    objectives, seeds, rules and planners (replaying, of a folder's attacks and planners), with the
    overrides every cell's params take."""

    source: Path
    name: str
    output: Path
    scenarios: tuple[Path, ...]
    objectives: tuple[str, ...] | None
    seeds: tuple[int, ...] | None
    rules: tuple[str, ...] | None
    planners: tuple[PlannerEntry, ...] | None
    overrides: Mapping[str, Any]
    executor: str
    workers: int
    ray_address: str | None
    thresholds: Mapping[str, float]
    replay: Path | None
    baseline: Path | None = None

    def fail(self, field: str, text: str) -> ParamsError:
        return _fail(self.source, field, text)


@dataclass(frozen=True)
class Cell:
    """One attack (or replay) of a campaign. Params travel as values (AttackParams holds a read-only
    mapping, which does not pickle) and are checked again where the cell runs."""

    name: str
    scenario: str
    objective: str
    seed: int
    planner: str
    values: Mapping[str, Any]  # AttackParams.canonical(): every value that decides the result
    source: Path | None  # the params file, where a relative bag is looked up
    attack: Path | None = None  # a replay cell: the results folder of the attack replayed
    role: str = ATTACK  # ATTACK, REPLAY, TRANSFER or BASELINE
    origin: str | None = None  # a transfer or baseline cell: the name of the attack's cell (where it was found)

    @property
    def key(self) -> tuple[str, str, int, str]:
        """(scenario, objective, seed, rule): what the cells that attack the same thing on other planners share."""
        return self.scenario, self.objective, self.seed, self.rule

    @property
    def rule(self) -> str:
        """The driving rule the cell attacks (a replay: that its attack was found under)."""
        rule: str = self.values[RULE]
        return rule

    @property
    def params(self) -> AttackParams:
        return params_from_values(self.values, self.source)

    @property
    def report_name(self) -> str:
        return REPORT_JSON if self.attack is None else REPLAY_JSON

    def report(self, output: Path) -> dict | None:
        """The finished cell's report, None while it is not finished; a ParamsError naming the file when
        it is no report of ours (truncated, not a mapping, without the fields a resume compares), which
        a resume must not take for a finished cell nor stop on with a traceback."""
        path = output / self.name / self.report_name
        if not path.is_file():
            return None
        try:
            report = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise ParamsError(f"{path}: not a finished cell's report ({exc}): remove the cell's folder to run it "
                              "again") from None
        missing = [field for field in FINISHED_FIELDS if not isinstance(report, dict) or field not in report]
        if missing:
            raise ParamsError(f"{path}: field '{missing[0]}' missing: not a finished cell's report; remove the "
                              "cell's folder to run it again")
        return report


def _fail(path: Path, field: str, text: str) -> ParamsError:
    return ParamsError(f"{path}: field '{field}' {text}")


FIELD_RULES = {
    "scenarios": "each a params file or a bag folder, by path",
    "objectives": f"each one of {', '.join(OBJECTIVES)}",
    "seeds": "each an integer >= 0",
    "rules": f"each one of {', '.join(RULES)}",
}


def _list(path: Path, document: dict, field: str, kind: type, check=None) -> tuple | None:
    """A non-empty list of `kind` (no repeats), each passing `check`; None when absent."""
    if field not in document:
        return None
    values = document[field]
    if not isinstance(values, list) or not values:
        raise _fail(path, field, f"must be a non-empty list, got {values!r}")
    for value in values:
        if not isinstance(value, kind) or isinstance(value, bool) or (check is not None and not check(value)):
            raise _fail(path, field, f"has {value!r}: {FIELD_RULES[field]}")
    if len(set(map(str, values))) != len(values):
        raise _fail(path, field, "lists a value twice")
    return tuple(values)


def _planner_entries(path: Path, raw: Any) -> tuple[PlannerEntry, ...]:
    if not isinstance(raw, list) or not raw:
        raise _fail(path, "planners", f"must be a non-empty list of {{name, planner, planner_params}}, got {raw!r}")
    entries = []
    for i, item in enumerate(raw):
        field = f"planners[{i}]"
        if not isinstance(item, dict) or set(item) - set(ENTRY_FIELDS) or "name" not in item:
            raise _fail(path, field,
                        f"must be a mapping with 'name' and optionally 'planner', 'planner_params', got {item!r}")
        if not isinstance(item["name"], str) or not LABEL.fullmatch(item["name"]):
            raise _fail(path, f"{field}.name",
                        f"must be a name of letters, digits, _ . + - (a folder name), got {item['name']!r}")
        if not isinstance(item.get("planner", ""), str):
            raise _fail(path, f"{field}.planner", f"must be a planner name, got {item['planner']!r}")
        if not isinstance(item.get(PLANNER_PARAMS, {}), dict):
            raise _fail(path, f"{field}.{PLANNER_PARAMS}", f"must be a mapping, got {item[PLANNER_PARAMS]!r}")
        entries.append(PlannerEntry(item["name"], item.get("planner"), item.get(PLANNER_PARAMS)))
    if len({entry.name for entry in entries}) != len(entries):
        raise _fail(path, "planners", "names a planner twice")
    return tuple(entries)


def _thresholds(path: Path, raw: Any) -> dict[str, float]:
    if not isinstance(raw, dict):
        raise _fail(path, "thresholds", f"must be a mapping of objective to metric, got {raw!r}")
    for objective, value in raw.items():
        if objective not in OBJECTIVES:
            raise _fail(path, "thresholds", f"names '{objective}', not one of {', '.join(OBJECTIVES)}")
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise _fail(path, f"thresholds.{objective}", f"must be a number, got {value!r}")
        low, high = THRESHOLD_RANGES[objective]
        if not low <= value <= high:  # NaN fails this too: a gate no attack can reach never fails CI
            raise _fail(path, f"thresholds.{objective}", f"must be a finite number in [{low:g}, {high:g}] "
                                                        f"(a threshold outside it no attack reaches), got {value!r}")
    return {objective: float(value) for objective, value in raw.items()}


def _found(path: Path, field: str, entry: str) -> Path:
    """A path the campaign names, looked up as a params file's bag is (`find_bag`): as given, next to
    the campaign file, then in the package share."""
    try:
        return find_bag(entry, path)
    except ParamsError:
        raise _fail(path, field, f"names '{entry}', which does not exist") from None


def load_campaign(path: str | Path, **changes: Any) -> Campaign:
    """The campaign file, its fields checked (the cells are checked by `plan`); `changes` replace
    fields (the command line's --output, --executor, --workers) and are checked the same way."""
    path = Path(path)
    document = read_yaml(path, "campaign file")
    if not isinstance(document, dict):
        raise ParamsError(f"{path}: a campaign file is a mapping of the fields {', '.join(FIELDS)}")
    document = {**document, **changes}
    unknown = sorted(str(key) for key in set(document) - set(FIELDS))
    if unknown:
        raise _fail(path, unknown[0], f"is not a campaign field (fields: {', '.join(FIELDS)})")
    for field in ("name", "output", "executor", "ray_address", "replay", "baseline"):
        if document.get(field) is not None and not isinstance(document[field], str):
            raise _fail(path, field, f"must be a string, got {document[field]!r}")
    name = document.get("name", path.stem)
    if not LABEL.fullmatch(name):
        raise _fail(path, "name", f"must be a name of letters, digits, _ . + - (a folder name), got {name!r}")
    executor = document.get("executor", "process")
    if executor not in EXECUTORS:
        raise _fail(path, "executor", f"must be one of {', '.join(EXECUTORS)}, got {executor!r}")
    workers = document.get("workers", os.cpu_count() or 1)
    if not isinstance(workers, int) or isinstance(workers, bool) or workers < 1:
        raise _fail(path, "workers", f"must be an integer >= 1, got {workers!r}")
    ray_address = _ray_address(path, document.get("ray_address"), executor)
    if executor == "ray" and find_spec("ray") is None:  # not imported here: RayExecutor sets its environment first
        raise _fail(path, "executor", "is ray, but ray is not installed: pip install 'advperc_ros[ray]'")
    overrides = document.get("overrides", {})
    if not isinstance(overrides, dict):
        raise _fail(path, "overrides", f"must be a mapping of dotted parameter names to values, got {overrides!r}")
    for key in overrides:
        if key in AXES:
            raise _fail(path, "overrides",
                        f"sets '{key}', which the cells vary: use scenarios, objectives, seeds, rules, planners")
        if key in EXECUTION:
            raise _fail(path, "overrides",
                        f"sets '{key}': campaign cells roll out embedded, the workers being the parallelism")
    replay = document.get("replay")
    baseline = document.get("baseline")
    axes = ("scenarios", "objectives", "seeds", "rules", "baseline")
    if replay is not None:
        given = [field for field in axes if field in document]
        if given:
            raise _fail(path, given[0], "does not apply to a replay campaign (its cells are the attacks in 'replay')")
    elif "scenarios" not in document:
        raise _fail(path, "scenarios", "is required (or 'replay')")
    scenarios = _list(path, document, "scenarios", str) or ()
    return Campaign(
        source=path,
        name=name,
        output=Path(document.get("output") or Path("results") / f"campaign-{name}"),
        scenarios=tuple(_found(path, f"scenarios[{i}]", entry) for i, entry in enumerate(scenarios)),
        objectives=_list(path, document, "objectives", str, lambda value: value in OBJECTIVES),
        seeds=_list(path, document, "seeds", int, lambda value: value >= 0),
        rules=_list(path, document, "rules", str, lambda value: value in RULES),
        planners=_planner_entries(path, document["planners"]) if "planners" in document else None,
        overrides=dict(overrides),
        executor=executor,
        workers=workers,
        ray_address=ray_address,
        thresholds=_thresholds(path, document.get("thresholds", {})),
        replay=_found(path, "replay", replay) if replay is not None else None,
        baseline=_found(path, "baseline", baseline) if baseline is not None else None,
    )


def _ray_address(path: Path, address: str | None, executor: str) -> str | None:
    """`ray_address` checked before any work: only with executor ray; HOST:PORT of a cluster's head, `auto`
    (the cluster `ray start` left running on this machine) or `ray://HOST:PORT` (Ray Client, which needs its
    gRPC library); and answering on that port within `RAY_REACH_TIMEOUT`. Ray itself, given an address that does
    not answer, retries for minutes; given one it cannot parse, it fails after the output folder is written."""
    if address is None:
        return None
    if executor != "ray":
        raise _fail(path, "ray_address", f"is for executor ray, but the executor is {executor}")
    target = address
    if address == "auto":
        if not RAY_CURRENT_CLUSTER.is_file():
            raise _fail(path, "ray_address", "is auto, but no Ray cluster runs on this machine (`ray start --head` "
                                             "starts one; or give its HOST:PORT)")
        target = RAY_CURRENT_CLUSTER.read_text().strip()
    host, sep, port = target.removeprefix(RAY_CLIENT).rpartition(":")
    if not sep or not HOST.fullmatch(host.strip("[]")) or not port.isdigit() or not 0 < int(port) < 65536:
        raise _fail(path, "ray_address", f"must be HOST:PORT, auto or ray://HOST:PORT, got {address!r}")
    if target.startswith(RAY_CLIENT) and find_spec("grpc") is None:
        raise _fail(path, "ray_address", f"is {address!r}, but Ray Client is not installed: pip install 'ray[client]'")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=RAY_REACH_TIMEOUT).close()
    except OSError as exc:
        raise _fail(path, "ray_address", f"nothing answers at {target} within {RAY_REACH_TIMEOUT:g} s "
                                         f"({exc.strerror or exc})") from None
    return address


def _label(planner: str) -> str:
    """A planner's name in cell names: a plug-in `module:Class` goes by its class."""
    return planner.rpartition(":")[2]


def _scenario_params(campaign: Campaign, index: int) -> tuple[str, AttackParams]:
    """(label, params) of a scenario: a params file's own, or the defaults on a bag folder."""
    path = campaign.scenarios[index]
    if path.is_dir():
        return path.name, AttackParams(bag=str(path))
    return path.stem, load_params(path)


def _checked(campaign: Campaign, field: str, change: Callable[..., AttackParams], **changes: Any) -> AttackParams:
    """Params the campaign changed, `change(**changes)`: a refusal names the campaign field that made it."""
    try:
        return change(**changes)
    except ParamsError as exc:
        raise campaign.fail(field, str(exc).split(": ", 1)[-1]) from None


def _planned(campaign: Campaign, base: AttackParams) -> list[tuple[AttackParams, str]]:
    """(params, planner label) per planner of the campaign: the scenario's own when it names none."""
    if campaign.planners is None:
        return [(base, _label(base.planner))]
    return [(_checked(campaign, f"planners[{i}]", entry.apply, params=base), entry.name)
            for i, entry in enumerate(campaign.planners)]


def _cell(name: str, scenario: str, params: AttackParams, planner: str, attack: Path | None = None,
          role: str = ATTACK, origin: str | None = None) -> Cell:
    return Cell(name, scenario, params.objective, params.seed, planner, params.canonical(), params.source, attack, role,
                origin)


def _rule_label(rule: str) -> str:
    """A rule's part of a cell name: none for the default, so that the cells of a campaign from before
    rules were an axis keep their names (and folders), and adding a rule to it runs only the new rule's."""
    return "" if rule == DEFAULT_RULE else f"-{rule}"


def _attack_cells(campaign: Campaign) -> list[Cell]:
    cells = []
    for index in range(len(campaign.scenarios)):
        label, scenario = _scenario_params(campaign, index)
        scenario = _checked(campaign, "overrides", scenario.with_values, **campaign.overrides)
        # each rule set before the other axes: a refusal (rule.at_fault_only of another rule) names `rules`
        ruled = [_checked(campaign, "rules", scenario.with_values, **{RULE: rule}) for rule in campaign.rules or ()]
        for objective in campaign.objectives or (scenario.objective,):
            for seed in campaign.seeds or (scenario.seed,):
                for rule_params in ruled or [scenario]:
                    base = _checked(campaign, "seeds", rule_params.with_values, objective=objective, seed=seed)
                    rule = _rule_label(base.rule.name)
                    for params, planner in _planned(campaign, base):
                        cells.append(_cell(f"{label}-{objective}-{seed}-{planner}{rule}", label, params, planner))
    return cells


def _replay_cells(campaign: Campaign, replay: Path) -> list[Cell]:
    """Every attack that collided in the `replay` folder, on each planner."""
    folders = sorted(folder for folder in replay.iterdir()
                     if not folder.name.startswith(".") and (folder / ERRORS).is_file())
    attacks = [load_attack(folder) for folder in folders]
    if not attacks:
        raise campaign.fail("replay", f"names {replay}, which holds no results folder of an attack that collided")
    cells = []
    for attack in attacks:
        base = _checked(campaign, "overrides", attack.params.with_values, **campaign.overrides)
        for params, planner in _planned(campaign, base):
            cells.append(_cell(f"{attack.folder.name}-on-{planner}", attack.report["scenario"], params, planner,
                               attack.folder, REPLAY))
    return cells


def transfer_cells(cells: list[Cell], found: Cell, output: Path) -> list[Cell]:
    """The attack of the finished cell `found` (which broke its rule) replayed on each other planner of the
    campaign: with the params of the cell that attacks the same scenario, objective, seed and rule on that
    planner, so that a row of the transfer matrix compares the planners exactly as the campaign attacks them."""
    return [Cell(f"{found.name}-on-{other.planner}", other.scenario, other.objective, other.seed, other.planner,
                 other.values, other.source, output / found.name, TRANSFER, found.name)
            for other in cells if other.role == ATTACK and other.key == found.key and other.planner != found.planner]


def _baseline_cells(campaign: Campaign, baseline: Path, cells: list[Cell]) -> list[Cell]:
    """Each attack the baseline run found, replayed on this campaign's cell of the same name (the same
    scenario, objective, seed, rule and planner name: the planner's next version, or its next params)."""
    try:
        rows = json.loads((baseline / SUMMARY_JSON).read_text())["cells"]
        found = {row["cell"] for row in rows if row.get("collision") and row.get("attack") is None}
    except (OSError, ValueError, TypeError, KeyError) as exc:
        raise campaign.fail("baseline", f"names {baseline}, which holds no campaign summary "
                                        f"({SUMMARY_JSON}: {exc})") from None
    replays = []
    for cell in cells:
        if cell.role != ATTACK or cell.name not in found:
            continue
        try:
            load_attack(baseline / cell.name)
        except INPUT_ERRORS as exc:
            raise campaign.fail("baseline", f"cell {cell.name}: {exc}") from None
        replays.append(Cell(cell.name + BASELINE_SUFFIX, cell.scenario, cell.objective, cell.seed, cell.planner, cell.values,
                            cell.source, baseline / cell.name, BASELINE, cell.name))
    return replays


def plan(campaign: Campaign) -> list[Cell]:
    """The campaign's cells in table order, checked: names unique and folder-safe, every bag read
    and every planner built once, and finished cells run with these very params."""
    if not campaign.output.is_dir():  # a folder there is a campaign to resume
        try:
            check_output(campaign.output, "output folder")
        except OutputError as exc:
            raise campaign.fail("output", str(exc)) from None
    cells = _replay_cells(campaign, campaign.replay) if campaign.replay is not None else _attack_cells(campaign)
    if campaign.baseline is not None:
        cells += _baseline_cells(campaign, campaign.baseline, cells)
    names = [cell.name for cell in cells]
    for cell in cells:
        if not LABEL.fullmatch(cell.name):
            raise campaign.fail("scenarios", f"makes cell name '{cell.name}', not a folder name (letters, digits, _ . + -)")
        if names.count(cell.name) > 1:
            raise campaign.fail("scenarios", f"makes cell '{cell.name}' twice: scenario and planner names must be unique")
    checked = set()
    for cell in cells:  # a stack per bag and planner configuration: bags readable, planners buildable
        params = cell.params
        system = json.dumps({k: v for k, v in cell.values.items() if k not in STACK_AXES}, sort_keys=True)
        if system not in checked:
            try:
                Stack(read_scenario(resolve_bag(params)), core_configs(params))
            except PluginError as exc:
                raise campaign.fail("planners" if campaign.planners else "scenarios", f"cell {cell.name}: {exc}") from None
            except INPUT_ERRORS as exc:
                raise campaign.fail("replay" if campaign.replay else "scenarios", f"cell {cell.name}: {exc}") from None
            checked.add(system)
    for cell in cells:
        finished_report(campaign, cell)
    return cells


def finished_report(campaign: Campaign, cell: Cell) -> dict | None:
    """The cell's report when it is finished (None while not), refused when it was finished with other params."""
    report = cell.report(campaign.output)
    if report is not None and report["config_hash"] != cell.params.config_hash():
        raise ParamsError(f"{campaign.output / cell.name}: finished with other params (config hash "
                          f"{report['config_hash']}, this campaign's {cell.params.config_hash()}): remove it or "
                          f"choose another output")
    return report
