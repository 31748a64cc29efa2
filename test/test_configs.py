"""One path from params to the core: the core configs' defaults are the schema's, the registries
are the schema's choices, and `core_configs` builds what the params say."""

import dataclasses

import pytest

from advperc_ros.backends.registry import BACKENDS, backend_class
from advperc_ros.configs import EGO, TABLES, core_configs
from advperc_ros.core.planners.base import PlanningContext
from advperc_ros.core.search.registry import METHODS, method_class
from advperc_ros.params import SCHEMA, AttackParams

# core defaults that differ from the schema's on purpose: a RolloutConfig built in a library or a
# test has no plan timeout (no alarm); an attack always takes graph.timeout from its params
NOT_THE_SCHEMAS = {("RolloutConfig", "plan_timeout")}


@pytest.mark.parametrize("config, table", TABLES, ids=[config.__name__ for config, _ in TABLES])
def test_every_core_default_is_the_schemas(config, table):
    defaults = {f.name: f.default for f in dataclasses.fields(config)}
    for name, dotted in table.items():
        if (config.__name__, name) in NOT_THE_SCHEMAS:
            continue
        assert defaults[name] == SCHEMA[dotted].default, f"{config.__name__}.{name} != schema {dotted}"


def test_every_table_names_schema_parameters_and_config_fields():
    for config, table in [*TABLES, (PlanningContext, EGO)]:
        names = {f.name for f in dataclasses.fields(config)}
        assert set(table) <= names and set(table.values()) <= set(SCHEMA), config.__name__


def test_core_configs_follow_the_params():
    params = AttackParams(bag="b").with_values(**{"tracker.gate": 3.0, "search.random.steps": 7, "rule.at_fault_only": True,
                                                  "search.guided.batch": 5, "seed": 9, "graph.timeout": 2.0})
    configs = core_configs(params)
    assert configs.tracker.gate == 3.0 and configs.rollout.at_fault_only and configs.rollout.plan_timeout == 2.0
    assert configs.search.random.steps == 7 and configs.search.guided.random.steps == 7
    assert configs.search.guided.batch == 5 and configs.search.seed == 9


def test_the_registries_are_the_schemas_choices():
    assert tuple(METHODS) == SCHEMA["search.method"].choices
    assert tuple(BACKENDS) == SCHEMA["rollout_backend"].choices
    for name in METHODS:
        assert method_class(name).name == name
    assert backend_class("embedded").__name__ == "Stack"
