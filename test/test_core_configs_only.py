"""CoreConfigs is all that sits below the application needs: backends read no params, and the
configs carry what they used to read there (planner, footprint, profile, execution, identity)."""

import ast
import json
from pathlib import Path

from advperc_ros.configs import core_configs
from advperc_ros.params import AttackParams

BACKENDS = Path(__file__).resolve().parent.parent / "advperc_ros" / "backends"


def test_no_backend_module_imports_the_params():
    for path in sorted(BACKENDS.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([node.module or ""] if isinstance(node, ast.ImportFrom)
                     else [alias.name for alias in node.names] if isinstance(node, ast.Import) else [])
            assert not any(name == "advperc_ros.params" or name.startswith("advperc_ros.params.") for name in names), path


def test_the_configs_carry_what_a_backend_reads():
    params = AttackParams(bag="b", planner="obp", planner_params={"horizon": 3.0}).with_values(
        **{"ego.length": 5.0, "ego.width": 2.0, "workers": 3, "rollout_backend": "graph", "graph.spawn_nodes": False,
           "graph.drive": "clock", "graph.timeout": 4.0, "dds.domain_id": 7, "dds.localhost_only": False,
           "graph.interface": "autoware"})
    configs = core_configs(params)
    assert (configs.footprint.ego_length, configs.footprint.ego_width) == (5.0, 2.0)
    assert configs.planner.name == "obp" and dict(configs.planner.params) == {"horizon": 3.0}
    assert configs.profile.name == "autoware"
    execution = configs.execution
    assert (execution.backend, execution.workers, execution.spawn_nodes, execution.drive, execution.graph_timeout,
            execution.domain_id, execution.localhost_only) == ("graph", 3, False, "clock", 4.0, 7, False)
    assert execution.node_values == params.values()
    assert json.loads(configs.canonical) == params.canonical()
    assert core_configs(params.with_values(workers=1)).canonical == configs.canonical  # execution is not identity
    assert core_configs(params.with_values(seed=1)).canonical != configs.canonical
