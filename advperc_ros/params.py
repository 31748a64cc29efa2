"""The orchestrator's parameters: one schema for the params file, the CLI and the ROS 2 node.

A params file uses the ROS layout (`orchestrator: ros__parameters: ...`, nested mappings become
dotted names), so the same file serves `advperc attack` and `ros2 run ... --params-file`. Types are
as strict as ROS 2's: a YAML `1` where a float is declared is refused, and so is any unknown key.
Everything is checked before any work starts; errors name the file and the parameter.
"""

import hashlib
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

NODE = "orchestrator"
PACKAGE = "advperc_ros"


class ParamsError(ValueError):
    """A params file that cannot be used; the message names the file and the parameter."""


@dataclass(frozen=True)
class Param:
    type: type
    default: Any
    description: str
    choices: tuple[str, ...] = ()


SCHEMA: dict[str, Param] = {
    "bag": Param(str, None, "ground-truth rosbag2 bag to attack (directory); relative paths are tried "
                 "against the working directory, then the params file's directory, then the package share"),
    "planner": Param(str, "idm", "bundled planner name or a plug-in as module:Class"),
    "objective": Param(str, "nds_t", "perception metric the search maximises", ("nds", "nds_t", "pem_ll")),
    "seed": Param(int, 0, "seed of the random search; same params and seed give the same attack"),
    "stop_at_collision": Param(bool, True, "end a rollout at its first rule violation"),
    "ego.length": Param(float, 4.6, "ego box length (m)"),
    "ego.width": Param(float, 1.9, "ego box width (m)"),
    "tracker.gate": Param(float, 2.0, "association gate on centre distance (m)"),
    "tracker.max_age": Param(float, 1.0, "seconds without an observation before a track is deleted"),
    "search.heuristic.iterations": Param(int, 3, "bisection iterations for each bound (paper: 3)"),
    "search.random.steps": Param(int, 40, "random search steps N_steps (paper: 40)"),
    "search.random.proposals": Param(int, 100, "proposals per step N_proposal (paper: 100)"),
    "search.random.max_offset": Param(float, 5.0, "largest position offset of a flipped segment (m)"),
    "search.random.yaw_std": Param(float, 0.1, "yaw noise of flipped detections (rad)"),
    "search.refine.iterations": Param(int, 4, "beyond the paper: bisection iterations re-detecting the start of "
                                      "each dropped run of the best attack; 0 keeps the paper's search only"),
    "rollout_backend": Param(str, "embedded", "how rollouts run: in this process (embedded) or through the node "
                             "graph over DDS (graph); both give the same results", ("embedded", "graph")),
    "dds.domain_id": Param(int, 0, "DDS domain id of the graph backend (0..232)"),
    "dds.localhost_only": Param(bool, True, "graph backend: DDS discovery and traffic on this host's loopback only"),
    "graph.timeout": Param(float, 10.0, "graph backend: seconds the player waits for a frame's plan and rule "
                           "value before the rollout is inconclusive"),
    "graph.spawn_nodes": Param(bool, True, "graph backend: start the five graph nodes as child processes (Cyclone "
                               "DDS); false uses nodes already running, e.g. from launch/attack.launch.py"),
}
EXECUTION = ("rollout_backend", "dds.domain_id", "dds.localhost_only", "graph.timeout", "graph.spawn_nodes")
"""How rollouts are executed, not what they compute: left out of the report's params and the config
hash, so the graph and embedded backends give the same report."""
PLANNER_PARAMS = "planner_params"  # free mapping handed to the planner's constructor


@dataclass(frozen=True)
class AttackParams:
    values: dict[str, Any]  # every SCHEMA key, validated
    planner_params: dict[str, Any]
    source: Path | None

    def __getitem__(self, name: str) -> Any:
        return self.values[name]

    def with_values(self, **changes: Any) -> "AttackParams":
        """These params with some values replaced (names with dots: pass via **{"a.b": v})."""
        unknown = set(changes) - set(SCHEMA)
        if unknown:
            raise ParamsError(f"unknown parameter '{sorted(unknown)[0]}'")
        return AttackParams({**self.values, **changes}, self.planner_params, self.source)

    def canonical(self) -> dict[str, Any]:
        """What determines the results: every value but the EXECUTION ones, and the planner's."""
        values = {name: value for name, value in self.values.items() if name not in EXECUTION}
        return {**values, PLANNER_PARAMS: self.planner_params}

    def config_hash(self) -> str:
        return hashlib.sha256(json.dumps(self.canonical(), sort_keys=True).encode()).hexdigest()[:16]


def nest(flat: dict[str, Any]) -> dict[str, Any]:
    """Dotted parameter names back into the nested mapping of a params file."""
    out: dict[str, Any] = {}
    for name, value in flat.items():
        node = out
        *parents, leaf = name.split(".")
        for key in parents:
            node = node.setdefault(key, {})
        node[leaf] = value
    return out


def _flatten(mapping: dict, prefix: str = "") -> dict[str, Any]:
    out = {}
    for key, value in mapping.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict) and name != PLANNER_PARAMS:
            out.update(_flatten(value, f"{name}."))
        else:
            out[name] = value
    return out


def _check_type(where: str, name: str, value: Any, param: Param) -> Any:
    expected = param.type
    ok = isinstance(value, expected) and not (expected is int and isinstance(value, bool))
    if expected is float and isinstance(value, int) and not isinstance(value, bool):
        raise ParamsError(f"{where}: parameter '{name}' must be a float (write {value}.0), got integer {value}")
    if not ok:
        raise ParamsError(f"{where}: parameter '{name}' must be of type {expected.__name__}, got {type(value).__name__} {value!r}")
    if expected is float and value != value:
        raise ParamsError(f"{where}: parameter '{name}' is NaN")
    if param.choices and value not in param.choices:
        raise ParamsError(f"{where}: parameter '{name}' must be one of {', '.join(param.choices)}, got {value!r}")
    return value


def _check_planner_params(where: str, raw: Any) -> dict[str, Any]:
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        raise ParamsError(f"{where}: parameter '{PLANNER_PARAMS}' must be a mapping")
    for key, value in raw.items():
        if not isinstance(value, (bool, int, float, str)) or (isinstance(value, float) and value != value):
            raise ParamsError(f"{where}: parameter '{PLANNER_PARAMS}.{key}' must be a finite scalar, got {value!r}")
    return dict(raw)


def _check_ranges(where: str, values: dict[str, Any]) -> None:
    """Bounds the types cannot express, for the parameters present in `values`."""
    for name in ("search.heuristic.iterations", "search.random.steps", "search.random.proposals",
                 "search.refine.iterations"):
        if name in values and values[name] < 0:
            raise ParamsError(f"{where}: parameter '{name}' must not be negative")
    for name in ("ego.length", "ego.width", "tracker.gate", "tracker.max_age", "search.random.max_offset",
                 "graph.timeout"):
        if name in values and not values[name] > 0:
            raise ParamsError(f"{where}: parameter '{name}' must be positive")
    if "dds.domain_id" in values and not 0 <= values["dds.domain_id"] <= 232:
        raise ParamsError(f"{where}: parameter 'dds.domain_id' must be within 0..232, got {values['dds.domain_id']}")


def node_values(flat: dict[str, Any], names: tuple[str, ...], where: str,
                takes_planner_params: bool = False) -> tuple[dict[str, Any], dict[str, Any]]:
    """A graph node's parameters as ROS hands them over (dotted names, one by one rather than as a
    file), checked as strictly as a params file: (its `names` values, the planner's keyword
    arguments given as `planner_params.<key>` if it takes them). Any other name is refused, so no
    override a user types is silently ignored."""
    prefix = f"{PLANNER_PARAMS}."
    planner_params = {name[len(prefix):]: value for name, value in flat.items()
                      if takes_planner_params and name.startswith(prefix)}
    for name in flat:
        if name not in names and not (takes_planner_params and name.startswith(prefix)):
            takes = [*names, *([f"{prefix}<key>"] if takes_planner_params else [])]
            raise ParamsError(f"{where}: unknown parameter '{name}' (this node takes: {', '.join(takes) or 'none'})")
    values = {}
    for name in names:
        param = SCHEMA[name]
        if flat.get(name) is None:
            if param.default is None:
                raise ParamsError(f"{where}: parameter '{name}' is required")
            values[name] = param.default
        else:
            values[name] = _check_type(where, name, flat[name], param)
    _check_ranges(where, values)
    return values, _check_planner_params(where, planner_params)


def parse_params(document: Any, where: str, source: Path | None = None) -> AttackParams:
    if not isinstance(document, dict) or NODE not in document:
        raise ParamsError(f"{where}: expected a top-level '{NODE}:' mapping with 'ros__parameters:'")
    unknown_nodes = sorted(set(document) - {NODE})
    if unknown_nodes:
        raise ParamsError(f"{where}: unknown node '{unknown_nodes[0]}' (only '{NODE}' is configured here)")
    node = document[NODE]
    if not isinstance(node, dict) or not isinstance(node.get("ros__parameters"), dict) or len(node) != 1:
        raise ParamsError(f"{where}: '{NODE}' must hold exactly one mapping 'ros__parameters:'")
    flat = _flatten(node["ros__parameters"])
    planner_params = _check_planner_params(where, flat.pop(PLANNER_PARAMS, None))
    for name in flat:
        if name not in SCHEMA:
            raise ParamsError(f"{where}: unknown parameter '{name}'")
    values = {}
    for name, param in SCHEMA.items():
        if name in flat:
            values[name] = _check_type(where, name, flat[name], param)
        elif param.default is None:
            raise ParamsError(f"{where}: parameter '{name}' is required")
        else:
            values[name] = param.default
    _check_ranges(where, values)
    return AttackParams(values=values, planner_params=planner_params, source=source)


def load_params(path: str | Path) -> AttackParams:
    path = Path(path)
    try:
        document = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ParamsError(f"{path}: no such params file") from None
    except (OSError, yaml.YAMLError) as exc:
        raise ParamsError(f"{path}: cannot read params file: {exc}".replace("\n", " ")) from exc
    return parse_params(document, str(path), path)


def package_share() -> Path:
    """Where this package's shared files (bags/, config/, launch/) are installed: ament_index knows
    a colcon or ROS install; a plain pip install puts them under Python's prefix."""
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError:
        return Path(sys.prefix) / "share" / PACKAGE
    try:
        return Path(get_package_share_directory(PACKAGE))
    except PackageNotFoundError:
        return Path(sys.prefix) / "share" / PACKAGE


def find_bag(bag: str, source: Path | None) -> Path:
    """The bag a params file names, in one order for every way of running: as given (absolute, or
    relative to the working directory), relative to the params file `source`, then in the package
    share (`package_share`)."""
    name = Path(bag)
    candidates = [name]
    if not name.is_absolute():
        if source is not None:
            candidates.append(source.parent / name)
        candidates.append(package_share() / name)
    for candidate in candidates:
        if candidate.exists():
            return candidate
    tried = ", ".join(str(c) for c in candidates)
    raise ParamsError(f"{source or 'params'}: parameter 'bag' names '{name}', which does not exist (tried {tried})")


def resolve_bag(params: AttackParams) -> Path:
    """The bag named in the params, found by `find_bag`."""
    return find_bag(params["bag"], params.source)
