"""The orchestrator's parameters: one typed schema for the params file, the CLI and every ROS node.

- `schema`: `AttackParams`, its groups and `SCHEMA` (every parameter's type, default, bounds);
- `tree`: dotted values, the params file's nested mapping and `AttackParams` into one another;
- `strict_yaml`: params files read strictly (`load_params`);
- `install`: where a params file's bag is (`resolve_bag`), the package share included.
"""

from advperc_ros.exceptions import ParamsError
from advperc_ros.params.install import PACKAGE, find_bag, package_share, resolve_bag
from advperc_ros.params.schema import (
    EXECUTION,
    INTERFACES,
    NODE,
    PLANNER_PARAMS,
    RULE_SECTIONS,
    RULE_THRESHOLDS,
    SCHEMA,
    TRAFFIC_PARAMS,
    AttackParams,
    Param,
    rule_parameter,
)
from advperc_ros.params.strict_yaml import load_params, read_yaml
from advperc_ros.params.tree import nest, node_values, params_from_values, parse_params

__all__ = ["EXECUTION", "INTERFACES", "NODE", "PACKAGE", "PLANNER_PARAMS", "RULE_SECTIONS", "RULE_THRESHOLDS", "SCHEMA",
           "TRAFFIC_PARAMS", "AttackParams", "Param", "ParamsError", "find_bag", "load_params", "nest", "node_values",
           "package_share", "params_from_values", "parse_params", "read_yaml", "resolve_bag", "rule_parameter"]
