"""The orchestrator's parameters: one typed schema for the params file, the CLI and every ROS node.

`AttackParams` is a tree of frozen dataclasses (`params.search.random.steps`), validated whenever
one is built, overrides included. Its fields are the schema: each carries its type, default,
description and bounds, and `SCHEMA` lists them under the dotted names ROS uses
(`search.random.steps`). Types are as strict as ROS 2's: a YAML `1` where a float is declared is
refused. Errors name the file and the parameter.
"""

import dataclasses
import hashlib
import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, cast

from advperc_ros.core.parameters import parameter_info
from advperc_ros.core.perception_errors import ERROR_KINDS, PAPER_KINDS, parse_error_kinds
from advperc_ros.core.perception_errors.registry import bounds as error_bounds
from advperc_ros.core.perception_errors.restriction import MAGNITUDES, Restriction
from advperc_ros.core.rules.registry import RULES, rule_class
from advperc_ros.core.rules.verdict import CONTACT_RULES, DEFAULT_RULE
from advperc_ros.core.search.registry import METHODS
from advperc_ros.core.traffic import IDMParameters
from advperc_ros.exceptions import ParamsError
from advperc_ros.ros.interfaces.registry import BUNDLED as INTERFACES
from advperc_ros.ros.interfaces.registry import DEFAULT as DEFAULT_INTERFACE

NODE = "orchestrator"
PLANNER_PARAMS = "planner_params"  # free mapping handed to the planner's constructor
INT64_MAX = 2**63 - 1  # a ROS integer parameter is an int64



@dataclass(frozen=True)
class Param:
    """One parameter of the schema: what `AttackParams` checks and the ROS nodes declare."""

    type: type
    default: Any
    description: str
    choices: tuple[str, ...] = ()
    low: float | None = None  # smallest value allowed
    positive: bool = False  # strictly above `low` (0 when positive)
    high: float | None = None
    parse: Callable[[Any], Any] | None = None  # the value's own rule beyond type and bounds (a ValueError says why)

    def check(self, name: str, value: Any) -> Any:
        """`value` if it fits, else a ParamsError naming `name` (no file: the caller adds it)."""
        expected = self.type
        if expected is float and isinstance(value, int) and not isinstance(value, bool):
            raise ParamsError(f"parameter '{name}' must be a float (write {value}.0), got integer {value}")
        if not isinstance(value, expected) or (expected is int and isinstance(value, bool)):
            raise ParamsError(f"parameter '{name}' must be of type {expected.__name__}, "
                              f"got {type(value).__name__} {value!r}")
        if self.choices and value not in self.choices:
            raise ParamsError(f"parameter '{name}' must be one of {', '.join(self.choices)}, got {value!r}")
        if self.parse is not None:
            try:
                self.parse(value)
            except ValueError as exc:
                raise ParamsError(f"parameter '{name}': {exc}") from None
        if expected not in (int, float):
            return value
        number = cast(float, value)  # an int or a float, checked above
        if not math.isfinite(number):
            raise ParamsError(f"parameter '{name}' must be a finite number, got {value}")
        if self.positive and not number > 0:
            raise ParamsError(f"parameter '{name}' must be positive, got {value}")
        if self.low is not None and number < self.low:
            raise ParamsError(f"parameter '{name}' must be at least {self.low:g}, got {value}")
        if self.high is not None and number > self.high:
            raise ParamsError(f"parameter '{name}' must be at most {self.high:g}, got {value}")
        return value


def _param(default: Any, description: str, **bounds: Any) -> Any:
    """A dataclass field whose metadata is its `Param` (type filled in from the annotation)."""
    return field(default=default, metadata={"param": (description, bounds)})


@dataclass(frozen=True)
class EgoParams:
    """The ego's box: the rule monitor's collisions and a planner's footprint are both measured with it."""

    length: float = _param(4.6, "ego box length (m): at most a road train's 60 m", positive=True, high=60.0)
    width: float = _param(1.9, "ego box width (m): at most a lane's 5 m", positive=True, high=5.0)


@dataclass(frozen=True)
class RuleChoice:
    """The driving rule the search attacks (the paper's collision rule by default; docs/rules.md) and, of
    the collision rule, which contacts count: every one or only the ego's fault. `RuleParams` adds each
    rule's thresholds."""

    name: str = _param(DEFAULT_RULE, "the driving rule the search attacks, r < 0 a violation (docs/rules.md): "
                       f"{', '.join(RULES)}", choices=tuple(RULES))
    at_fault_only: bool = _param(False, "count only collisions that are the ego's fault (nuPlan's at-fault "
                                 "collisions): not when the ego is stopped or hit from behind; the same as "
                                 "rule.name at_fault_collision")


def rule_parameter(rule: str, parameter: str) -> str:
    """The dotted name of a rule's threshold in the params: `rule.<rule>.<parameter>`."""
    return f"rule.{rule}.{parameter}"


def _rule_section(name: str) -> type | None:
    """The params section `rule.<name>` of a rule the search judges apart from the rollout: its fields are
    the rule's parameters, with the rule's defaults, sources and bounds (one definition, in the rule's
    module). None for a rule without parameters, and for the contact rules, which every backend judges
    itself as the rollout runs, at their fixed thresholds."""
    infos = parameter_info(rule_class(name).Parameters)
    if name in CONTACT_RULES or not infos:
        return None
    fields_ = [(i.name, float, _param(i.default, f"{name}: {i.source}", low=i.bounds.low, high=i.bounds.high,
                                      positive=i.bounds.positive)) for i in infos]
    doc = f"The thresholds of rule {name} (docs/rules.md), at its defaults unless the params file sets them."
    return dataclasses.make_dataclass(f"{name.title().replace('_', '')}Params", fields_, frozen=True,
                                      namespace={"__doc__": doc})


RULE_SECTIONS = {name: section for name in RULES if (section := _rule_section(name)) is not None}
RuleParams: type[RuleChoice] = dataclasses.make_dataclass(
    "RuleParams", [(name, section, field(default=section())) for name, section in RULE_SECTIONS.items()],
    bases=(RuleChoice,), frozen=True,
    namespace={"__doc__": "The attacked rule (`RuleChoice`) and, under `rule.<rule>.<parameter>`, every rule's "
                          "thresholds: what the search, the report and the rule monitor judge rollouts by."})
RULE_DEFAULTS = RuleParams()
RULE_THRESHOLDS = tuple(rule_parameter(name, f.name) for name, section in RULE_SECTIONS.items()
                        for f in dataclasses.fields(section))
"""Every rule threshold's dotted name (`rule.<rule>.<parameter>`): what a node that judges rules declares."""


def _traffic_section() -> type:
    """The params section `traffic`: whether agents react to the ego, and the driver model's parameters with
    the model's defaults, sources and bounds (one definition, in core.traffic)."""
    fields_: list[tuple[str, type, Any]] = [("reactive", bool, _param(
        False, "agents keep their recorded paths but brake for the ego (IDM, as nuPlan's reactive agents; "
               "docs/traffic.md); false: they replay their recording whatever the ego does, as in the paper"))]
    fields_ += [(i.name, float, _param(i.default, f"reactive traffic: {i.source}", low=i.bounds.low, high=i.bounds.high,
                                       positive=i.bounds.positive)) for i in parameter_info(IDMParameters)]
    doc = ("How the agents move: replayed (the default) or reacting to the ego along their recorded paths, with "
           "the driver model's parameters (`traffic.<parameter>`, read only when `traffic.reactive`).")
    return dataclasses.make_dataclass("TrafficParams", fields_, frozen=True, namespace={"__doc__": doc})


TrafficParams = _traffic_section()
TRAFFIC_DEFAULTS = TrafficParams()
TRAFFIC_PARAMS = tuple(f"traffic.{f.name}" for f in dataclasses.fields(TrafficParams))
"""Every traffic parameter's dotted name: what the node that moves the agents (the scenario player) declares."""


@dataclass(frozen=True)
class TrackerParams:
    """The bundled tracker's association and deletion: what turns detections into the tracks a planner sees."""

    gate: float = _param(2.0, "association gate on centre distance (m)", positive=True)
    max_age: float = _param(1.0, "seconds without an observation before a track is deleted", positive=True)


@dataclass(frozen=True)
class HeuristicParams:
    """The paper's first phase, which bisects each agent's drop window before any random search."""

    iterations: int = _param(3, "bisection iterations for each bound (paper: 3)", low=0, high=64)


@dataclass(frozen=True)
class JointParams:
    """Drops of several agents at once: our step for scenarios where no single drop makes the ego collide."""

    max_agents: int = _param(8, "beyond the paper, when no single agent's drop collides: agents the joint drops "
                             "keep at most (README Search); 0: no joint drops (nor the blind rollout)", low=0,
                             high=1_000_000)


@dataclass(frozen=True)
class ApproachParams:
    """Our approach phase: the nearest cars displaced or hidden a while, where no drop at all collides."""

    steps: int = _param(120, "beyond the paper, when no drop collides (not even the blind rollout): rollouts of "
                        "the approach phase at most, which shows the cars nearest the ego displaced or hidden for a "
                        "while (README Search); 0: none",
                        low=0, high=1_000_000)
    patience: int = _param(30, "rollouts in a row that bring the ego no nearer a collision at its fault before the "
                           "approach phase gives up", low=1, high=1_000_000)


@dataclass(frozen=True)
class RandomParams:
    """The paper's random search: its steps, the proposals scored per step and the size of a flip."""

    steps: int = _param(40, "random search steps N_steps (paper: 40)", low=0, high=1_000_000)
    # each proposal is an error tensor held at once (frames x agents x 25 bytes): 10,000 of a 44-car recording
    # take about 0.9 GB, where a million took tens of GB and ended in a MemoryError after the work had started
    proposals: int = _param(100, "proposals per step N_proposal (paper: 100)", low=1, high=10_000)
    max_offset: float = _param(5.0, "largest position offset of a flipped segment (m)", positive=True)
    yaw_std: float = _param(0.1, "yaw noise of flipped detections (rad)", low=0.0)


@dataclass(frozen=True)
class RefineParams:
    """Our refinement of the best attack's drop starts, after the paper's search has found it."""

    iterations: int = _param(4, "beyond the paper: bisection iterations re-detecting the start of each dropped "
                             "run of the best attack; 0 keeps the paper's search only", low=0, high=64)


@dataclass(frozen=True)
class GuidedParams:
    """The guided method's rounds: many candidates scored exactly, a few of them rolled out."""

    candidates: int = _param(400, "guided method: candidates scored exactly per round (held at once, as the "
                             "random search's proposals)", low=1, high=10_000)
    batch: int = _param(2, "guided method: rollouts per round (they may run at once on `workers`)", low=1, high=1024)


@dataclass(frozen=True)
class ErrorKindsChoice:
    """The error kinds the search may use; `ErrorsParams` adds every kind's bounds."""

    kinds: str = _param("paper", "error kinds the search may use: paper (position, yaw and drop, the paper's: its "
                        "results bit for bit), all, or a comma-separated list of the kinds added to the paper's: "
                        + ", ".join(ERROR_KINDS[len(PAPER_KINDS):]) + " (docs/errors.md)", parse=parse_error_kinds)


ErrorsParams: type[ErrorKindsChoice] = dataclasses.make_dataclass(
    "ErrorsParams",
    [(bound.name, type(bound.default), _param(bound.default, bound.description, low=bound.low, high=bound.high,
                                              positive=bound.positive)) for bound in error_bounds().values()],
    bases=(ErrorKindsChoice,), frozen=True,
    namespace={"__doc__": "The error space the search may use (`ErrorKindsChoice`) and the bounds each kind beyond "
                          "the paper's three declares (`ErrorKind.bounds`: one definition, in the kind's module)."})
ERRORS_DEFAULTS = ErrorsParams()


@dataclass(frozen=True)
class RequirementParams:
    """The error space of one perception requirement, which `advperc requirements` sets per search: one error
    kind, at one range of distances from the ego, bounded by one magnitude (`core.perception_errors.restriction`).
    Off (`kind` empty) in an ordinary attack, whose report and config hash then do not mention it."""

    kind: str = _param("", "requirement search: the one error kind the search may use, each error tensor projected "
                       "onto it (docs/requirements.md); empty: off. " + "; ".join(
                           f"{name}: {m.description} ({m.unit})" for name, m in MAGNITUDES.items()),
                       choices=("", *MAGNITUDES))
    magnitude: float = _param(0.0, "requirement search: the largest error of that kind, in its unit", low=0.0,
                              high=1e6)
    near: float = _param(0.0, "requirement search: errors only on cars at least this far from the ego (m)", low=0.0,
                         high=1e6)
    far: float = _param(0.0, "requirement search: and less far than this (m); 0: no limit", low=0.0, high=1e6)


@dataclass(frozen=True)
class SearchParams:
    """The search: its method, its rollout budget and each phase's settings, grouped as the file nests them."""

    method: str = _param("guided", "guided: heuristic, then rounds that score many candidates and roll out the "
                         "most promising (README Search); paper: heuristic, random search, refine, as the paper",
                         choices=tuple(METHODS))
    budget: int = _param(0, "rollouts the search may use at most; 0: the paper's search's bound (guided method: "
                         "what finding its failure mode took, plus the share of the paper's bound its random steps "
                         "and refine phase have)", low=0, high=1_000_000)
    heuristic: HeuristicParams = HeuristicParams()
    joint: JointParams = JointParams()
    approach: ApproachParams = ApproachParams()
    random: RandomParams = RandomParams()
    refine: RefineParams = RefineParams()
    guided: GuidedParams = GuidedParams()


@dataclass(frozen=True)
class DdsParams:
    """Where the bare-DDS graph talks: its domain, and whether it stays on loopback (the default)."""

    domain_id: int = _param(0, "DDS domain id of the graph backend (0..232)", low=0, high=232)
    localhost_only: bool = _param(True, "graph backend: DDS discovery and traffic on this host's loopback only")


@dataclass(frozen=True)
class GraphParams:
    """How the graph backend runs a rollout: timeouts, who starts the nodes, how frames reach the planner and
    which stack's messages it speaks."""

    timeout: float = _param(10.0, "seconds a frame's plan (graph backend: and rule value) may take before the "
                            "rollout is inconclusive; embedded, one plan call (at least 1 ms, a timer's tick)",
                            positive=True, low=1e-3, high=3600.0)
    spawn_nodes: bool = _param(True, "graph backend: start the five graph nodes as child processes (Cyclone DDS); "
                               "false uses nodes already running, e.g. from launch/attack.launch.py")
    drive: str = _param("messages", "graph backend: how the player hands frames to the planner: messages (a plan "
                        "answers every tracks message, stamped the same) or clock (for nodes on timers under use_sim_time: "
                        "/clock advances to each frame once its tracks are out; the first plan stamped from it to the "
                        "next frame is taken); docs/graph.md, Driving the planner", choices=("messages", "clock"))
    interface: str = _param(DEFAULT_INTERFACE, "graph backend: the message types and topic names the graph speaks to a "
                            "stack's own nodes (docs/stacks.md, Interface profiles)", choices=tuple(INTERFACES))


@dataclass(frozen=True)
class AttackParams:
    """Everything an attack is configured with; validated on construction."""

    bag: str = _param(None, "ground-truth rosbag2 bag to attack (directory); relative paths are tried against "
                      "the working directory, then the params file's directory, then the package share")
    planner: str = _param("idm", "bundled planner name or a plug-in as module:Class")
    objective: str = _param("nds_t", "perception metric the search maximises", choices=("nds", "nds_t", "pem_ll"))
    seed: int = _param(0, "seed of the search's random draws; same params and seed give the same attack", low=0,
                       high=INT64_MAX)
    stop_at_collision: bool = _param(True, "end a rollout at its first rule violation")
    attacked_layer: str = _param("detections", "where the errors go in: detections (the detector's output, before "
                                 "the tracker, as the paper) or tracks (the objects the planner reads, our tracker left "
                                 "out: for a team that brings only a planner)", choices=("detections", "tracks"))
    rule: RuleChoice = RULE_DEFAULTS
    ego: EgoParams = EgoParams()
    tracker: TrackerParams = TrackerParams()
    traffic: Any = TRAFFIC_DEFAULTS
    errors: ErrorKindsChoice = ERRORS_DEFAULTS
    search: SearchParams = SearchParams()
    requirement: RequirementParams = RequirementParams()
    workers: int = _param(1, "embedded backend: processes that run a guided round's rollouts at once; the attack "
                          "is the same whatever the number", low=1, high=256)
    fork_memory: int = _param(256, "embedded backend: MB of snapshots each process keeps, so that a rollout starts "
                              "from the frame its detections first differ from an earlier rollout's (0: every rollout "
                              "from frame 0); the attack is the same whatever the number", low=0, high=1 << 20)
    rollout_backend: str = _param("embedded", "how rollouts run: in this process (embedded) or through the node graph "
                                  "over DDS (graph); both give the same results", choices=("embedded", "graph"))
    dds: DdsParams = DdsParams()
    graph: GraphParams = GraphParams()
    planner_params: Mapping[str, Any] = field(default_factory=dict)  # the planner's constructor keywords
    source: Path | None = field(default=None, compare=False)  # the params file, when there is one

    def __post_init__(self) -> None:
        where = str(self.source) if self.source is not None else "params"
        if self.bag is None:
            raise ParamsError(f"{where}: parameter 'bag' is required")
        for name, param in SCHEMA.items():
            try:
                param.check(name, self.get(name))
            except ParamsError as exc:
                raise ParamsError(f"{where}: {exc}") from None
        if self.search.method == "paper" and parse_error_kinds(self.errors.kinds) != PAPER_KINDS:
            raise ParamsError(f"{where}: parameter 'errors.kinds' must be paper with search.method paper (the "
                              f"paper's search makes the paper's errors only); the guided method searches any kinds")
        requirement = self.requirement
        if requirement.kind:
            if requirement.far and requirement.far <= requirement.near:
                raise ParamsError(f"{where}: parameter 'requirement.far' must be above requirement.near "
                                  f"({requirement.near}), or 0 for no limit, got {requirement.far}")
            if requirement.kind not in parse_error_kinds(self.errors.kinds):
                raise ParamsError(f"{where}: parameter 'requirement.kind' is {requirement.kind}, which errors.kinds "
                                  f"({self.errors.kinds}) does not turn on")
            if self.search.method == "paper":
                raise ParamsError(f"{where}: parameter 'requirement.kind' needs search.method guided (the paper's "
                                  f"search makes the paper's errors only, unrestricted)")
        if self.rule.at_fault_only and self.rule.name not in CONTACT_RULES:
            raise ParamsError(f"{where}: parameter 'rule.at_fault_only' is true, but it is of the collision rule and "
                              f"rule.name is {self.rule.name}: set it false (or rule.name at_fault_collision)")
        object.__setattr__(self, PLANNER_PARAMS, MappingProxyType(check_planner_params(where, self.planner_params)))

    def get(self, name: str) -> Any:
        """A parameter by its dotted name (`search.random.steps`), as ROS names it."""
        value: Any = self
        for part in name.split("."):
            value = getattr(value, part)
        return value

    def flat(self) -> dict[str, Any]:
        """Every parameter of the schema by dotted name."""
        return {name: self.get(name) for name in SCHEMA}

    def with_values(self, **changes: Any) -> "AttackParams":
        """These params with some replaced (dotted names: pass via **{"a.b": v}), validated again."""
        unknown = sorted(set(changes) - set(SCHEMA) - {PLANNER_PARAMS})
        if unknown:
            raise ParamsError(f"{self.source or 'params'}: unknown parameter '{unknown[0]}'")
        return params_from_values({**self.values(), **changes}, self.source)

    def values(self) -> dict[str, Any]:
        """Every value by dotted name and the planner's as a plain dict: what `params_from_values`
        takes back (in another process too: it pickles and serialises as JSON)."""
        return {**self.flat(), PLANNER_PARAMS: dict(self.planner_params)}

    def canonical(self) -> dict[str, Any]:
        """What determines the results: every value but the EXECUTION ones, and the planner's; the requirement's
        only when it is on, so that an ordinary attack's identity is what it was before requirements."""
        off = () if self.requirement.kind else REQUIREMENT
        return {name: value for name, value in self.values().items() if name not in EXECUTION and name not in off}

    def restriction(self) -> Restriction | None:
        """The requirement's error space, None when off."""
        requirement = self.requirement
        if not requirement.kind:
            return None
        return Restriction(requirement.kind, requirement.magnitude, requirement.near, requirement.far or math.inf)

    def config_hash(self, **external_nodes: str | None) -> str:
        """16 hex digits of what determines the results: the canonical params, and the team's nodes that
        were attacked instead of ours (`planner_node=`, `tracker_node=`: their names as the middleware
        gives them; `planner_version=`: what the planner announced of itself), so that attacks of three
        external planners, or of two builds of one, are not one configuration."""
        identity = {**self.canonical(), **{key: node for key, node in sorted(external_nodes.items()) if node is not None}}
        return hashlib.sha256(json.dumps(identity, sort_keys=True).encode()).hexdigest()[:16]


def _section_type(f: dataclasses.Field) -> type | None:
    """The params dataclass of a section field, its default's type (a section built from the rulebook, as
    `rule`, is a subclass of its annotation); None for a parameter."""
    default = f.default
    return type(default) if dataclasses.is_dataclass(default) and not isinstance(default, type) else None


def _schema(cls: type, prefix: str = "") -> dict[str, Param]:
    """The dotted names and `Param`s of a params dataclass tree."""
    out: dict[str, Param] = {}
    for f in dataclasses.fields(cls):
        if (section := _section_type(f)) is not None:
            out.update(_schema(section, f"{prefix}{f.name}."))
        elif "param" in f.metadata:
            description, bounds = f.metadata["param"]
            out[f"{prefix}{f.name}"] = Param(cast(type, f.type), f.default, description, **bounds)
    return out


SCHEMA: dict[str, Param] = _schema(AttackParams)
REQUIREMENT = tuple(f"requirement.{f.name}" for f in dataclasses.fields(RequirementParams))
EXECUTION = ("workers", "fork_memory", "rollout_backend",
             "dds.domain_id", "dds.localhost_only", "graph.timeout", "graph.spawn_nodes",
             "graph.drive")
"""How rollouts are executed, not what they compute: left out of the report's params and the config
hash, so the graph and embedded backends give the same report."""


def check_planner_params(where: str, raw: Any) -> dict[str, Any]:
    """`planner_params` as a plain dict, or a ParamsError: a mapping of names to finite scalars (what a
    ROS parameter can carry, one `planner_params.<key>` each)."""
    if raw is None:
        return {}
    if not isinstance(raw, Mapping):
        raise ParamsError(f"{where}: parameter '{PLANNER_PARAMS}' must be a mapping")
    for key, value in raw.items():
        if not isinstance(key, str):
            raise ParamsError(f"{where}: parameter '{PLANNER_PARAMS}' has a key that is not a name: {key!r}")
        if not isinstance(value, (bool, int, float, str)) or (isinstance(value, float) and not math.isfinite(value)):
            raise ParamsError(f"{where}: parameter '{PLANNER_PARAMS}.{key}' must be a finite scalar, got {value!r}")
    return dict(raw)


def _sections(cls: type, flat: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Constructor keywords of `cls` from dotted values (absent ones keep their defaults)."""
    kwargs: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        name = f"{prefix}{f.name}"
        if name in SCHEMA:
            if name in flat:
                kwargs[f.name] = flat[name]
        elif (section := _section_type(f)) is not None:
            kwargs[f.name] = section(**_sections(section, flat, f"{name}."))
    return kwargs


def params_from_values(flat: Mapping[str, Any], source: Path | None, where: str | None = None) -> AttackParams:
    """AttackParams from dotted values (and `planner_params`), as `AttackParams.flat()` gives them:
    unknown names refused; errors start with `where` (default: the params file)."""
    where = where or (str(source) if source is not None else "params")
    if flat.get("bag") is None:
        raise ParamsError(f"{where}: parameter 'bag' is required")
    planner_params = check_planner_params(where, flat.get(PLANNER_PARAMS))
    for name in flat:
        if name not in SCHEMA and name != PLANNER_PARAMS:
            raise ParamsError(f"{where}: unknown parameter '{name}'")
    for name, param in SCHEMA.items():  # types before construction: a section cannot take a wrong type
        if name in flat:
            try:
                param.check(name, flat[name])
            except ParamsError as exc:
                raise ParamsError(f"{where}: {exc}") from None
    return AttackParams(**_sections(AttackParams, flat), planner_params=planner_params, source=source)
