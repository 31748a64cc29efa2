"""The one path from the params tree to the core: every core config built in one place.

`core_configs(params)` builds them once, and the application hands the result down to the
backend, the checkpoint and the search, so nothing below the application reads params: a backend
is built from `CoreConfigs` alone (planner, footprint, interface profile, how rollouts execute). A graph node holds
only its own parameters (dotted values, not a whole params tree), so each config also has a
builder from dotted values, which `core_configs` uses too: one rule per config.

Which parameter fills which field is written once, in the tables below; a test checks that every
core config's default is the schema's default for the same parameter, so the two cannot drift.
"""

import json
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from advperc_ros.core.parameters import parameter_info
from advperc_ros.core.perception_errors import ErrorSpace, parse_error_kinds
from advperc_ros.core.perception_errors.registry import bounds as error_bounds
from advperc_ros.core.planners.base import PlanningContext
from advperc_ros.core.rollout import RolloutConfig
from advperc_ros.core.rules.registry import Rulebook, rule_class
from advperc_ros.core.scenario import Scenario
from advperc_ros.core.search.config import GuidedConfig, SearchConfig
from advperc_ros.core.search.random_search import RandomSearchConfig
from advperc_ros.core.tracker import TrackerConfig
from advperc_ros.core.traffic import IDMParameters
from advperc_ros.params import PLANNER_PARAMS, RULE_SECTIONS, AttackParams, rule_parameter
from advperc_ros.ros.interfaces.base import Profile
from advperc_ros.ros.interfaces.registry import load_profile

# core config field -> the dotted parameter that sets it
ROLLOUT = {"ego_length": "ego.length", "ego_width": "ego.width", "stop_at_collision": "stop_at_collision",
           "at_fault_only": "rule.at_fault_only", "plan_timeout": "graph.timeout"}
TRACKER = {"gate": "tracker.gate", "max_age": "tracker.max_age"}
RANDOM = {"steps": "search.random.steps", "proposals": "search.random.proposals",
          "max_offset": "search.random.max_offset", "yaw_std": "search.random.yaw_std"}
GUIDED = {"candidates": "search.guided.candidates", "batch": "search.guided.batch"}
SEARCH = {"heuristic_iterations": "search.heuristic.iterations", "joint_max_agents": "search.joint.max_agents",
          "approach_steps": "search.approach.steps", "approach_patience": "search.approach.patience",
          "refine_iterations": "search.refine.iterations", "seed": "seed", "method": "search.method",
          "budget": "search.budget"}
ERRORS = {name: f"errors.{name}" for name in error_bounds()}  # every kind's bounds; and `kinds`, from errors.kinds
EGO = {"ego_length": "ego.length", "ego_width": "ego.width"}  # of PlanningContext, whose other fields are the scenario's
EXECUTION = {"backend": "rollout_backend", "workers": "workers", "fork_memory": "fork_memory",
             "spawn_nodes": "graph.spawn_nodes",
             "drive": "graph.drive", "graph_timeout": "graph.timeout", "domain_id": "dds.domain_id",
             "localhost_only": "dds.localhost_only"}
TABLES: tuple[tuple[type, Mapping[str, str]], ...] = (
    (RolloutConfig, ROLLOUT), (TrackerConfig, TRACKER), (RandomSearchConfig, RANDOM), (GuidedConfig, GUIDED),
    (SearchConfig, SEARCH))
"""Every (core config, table) pair whose defaults must be the schema's (the error space's bounds have one
definition, the kinds' `Bound`s, which the schema and `ErrorSpace` both read)."""


def _fields(table: Mapping[str, str], values: Mapping[str, Any]) -> dict[str, Any]:
    return {name: values[dotted] for name, dotted in table.items()}


def rulebook(values: Mapping[str, Any]) -> Rulebook:
    """The thresholds every rule is judged by (`rule.<rule>.<parameter>`), from dotted values."""
    parameters = []
    for name in RULE_SECTIONS:
        cls = rule_class(name).Parameters
        parameters.append((name, cls(**{i.name: values[rule_parameter(name, i.name)] for i in parameter_info(cls)})))
    return Rulebook(tuple(parameters))


def traffic_model(values: Mapping[str, Any]) -> IDMParameters | None:
    """The reactive agents' driver model (`traffic.*`), or None when traffic replays its recording."""
    if not values["traffic.reactive"]:
        return None
    return IDMParameters(**{i.name: values[f"traffic.{i.name}"] for i in parameter_info(IDMParameters)})


def rollout_config(values: Mapping[str, Any]) -> RolloutConfig:
    """How a rollout is run and judged (ego footprint, rule, plan timeout, whether detections carry
    their velocity: the interface profile's detection type says), from dotted values."""
    carries = load_profile(values["graph.interface"]).detections.carries_velocity
    config = RolloutConfig(**_fields(ROLLOUT, values), detection_velocity=carries, traffic=traffic_model(values))
    return replace(config, at_fault_only=True) if values["rule.name"] == "at_fault_collision" else config


def tracker_config(values: Mapping[str, Any]) -> TrackerConfig:
    """The tracker's gate and track lifetime, from dotted values (the tracker node's own), and whether
    it is in the loop at all (`attacked_layer`: detections, as the paper, or the tracks themselves)."""
    return TrackerConfig(**_fields(TRACKER, values), in_loop=values["attacked_layer"] == "detections")


def planning_context(values: Mapping[str, Any], scenario: Scenario) -> PlanningContext:
    """What a planner is built with, from dotted values (the planner node's own) and the scenario."""
    return Footprint(**_fields(EGO, values)).context(scenario)


def error_kinds(params: AttackParams) -> tuple[str, ...]:
    """The error kinds the params' `errors.kinds` names, in the one order (`search_config`'s)."""
    return search_config(params.flat()).errors.kinds


def search_config(values: Mapping[str, Any]) -> SearchConfig:
    """The whole search's settings, from dotted values (`errors.kinds` parsed here, the one place)."""
    random = RandomSearchConfig(**_fields(RANDOM, values))
    errors = ErrorSpace(kinds=parse_error_kinds(values["errors.kinds"]), **_fields(ERRORS, values))
    return SearchConfig(**_fields(SEARCH, values), random=random,
                        guided=GuidedConfig(**_fields(GUIDED, values), random=random), errors=errors)


@dataclass(frozen=True)
class Footprint:
    """The ego's box a planner plans with (the rollout's rule measures with `RolloutConfig`'s, the same)."""

    ego_length: float
    ego_width: float

    def context(self, scenario: Scenario) -> PlanningContext:
        """What a planner is built with: the scenario's road and period, this footprint."""
        return PlanningContext(route=scenario.route, lanes=scenario.lanes, dt=scenario.dt, ego_length=self.ego_length,
                               ego_width=self.ego_width)


@dataclass(frozen=True)
class PlannerSpec:
    """Which planner the attack builds: a bundled name or `module:Class`, and its constructor's keywords."""

    name: str
    params: Mapping[str, Any]


@dataclass(frozen=True)
class ExecutionConfig:
    """How rollouts are executed, not what they compute (`params.EXECUTION`): which backend, the
    embedded backend's workers, and the graph backend's nodes, how long a silent graph is waited for
    (`graph.timeout`, which is also the rollout's `plan_timeout`) and DDS domain. `node_values`
    is what the graph's node processes are configured from (every dotted value and planner_params;
    each node takes its own), since they run apart from the process that read the params."""

    backend: str
    workers: int
    fork_memory: int  # MB of snapshots per process to fork rollouts from (core.forks); 0: none
    spawn_nodes: bool
    drive: str
    graph_timeout: float
    domain_id: int
    localhost_only: bool
    node_values: Mapping[str, Any]


@dataclass(frozen=True)
class CoreConfigs:
    """Everything below the application needs of one attack, built once from its params (`core_configs`):
    the core configs, the planner and its footprint, the interface profile and how rollouts execute."""

    rollout: RolloutConfig
    tracker: TrackerConfig
    search: SearchConfig
    footprint: Footprint
    planner: PlannerSpec
    profile: Profile
    execution: ExecutionConfig
    rulebook: Rulebook  # the thresholds of every rule: the attacked one's and the report's table's
    canonical: str  # the params that determine the results (`AttackParams.canonical`) as JSON: a checkpoint's identity

    def planning_context(self, scenario: Scenario) -> PlanningContext:
        """What the planner is built with: the scenario's road and period, the params' ego footprint."""
        return self.footprint.context(scenario)


def core_configs(params: AttackParams) -> CoreConfigs:
    """The core configs of an attack, from its params: what the backend, checkpoint and search use."""
    values = params.flat()
    node_values = params.values()
    return CoreConfigs(rollout=rollout_config(values), tracker=tracker_config(values), search=search_config(values),
                       footprint=Footprint(**_fields(EGO, values)),
                       planner=PlannerSpec(params.planner, node_values[PLANNER_PARAMS]),
                       profile=load_profile(params.graph.interface),
                       execution=ExecutionConfig(**_fields(EXECUTION, values), node_values=node_values),
                       rulebook=rulebook(values),
                       canonical=json.dumps(params.canonical(), sort_keys=True))
