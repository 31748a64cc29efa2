"""The README stays true: every parameter documented, both front-door commands as CI runs them."""

import re

from advperc_ros.params import PLANNER_PARAMS, SCHEMA


def test_every_parameter_is_documented(repo):
    readme = (repo / "README.md").read_text()
    for name in [*SCHEMA, PLANNER_PARAMS]:
        assert f"`{name}`" in readme, name


def test_ci_runs_the_readme_test_command(repo):
    readme = (repo / "README.md").read_text()
    blocks = re.findall(r"```bash\n(.*?)\n```", readme, flags=re.S)
    attack, tests = blocks[0].strip(), blocks[1].strip()
    assert attack.startswith("pip install . && advperc attack config/idm_lane_following.yaml")
    assert tests in (repo / ".ci" / "run").read_text()


def test_readme_params_table_is_the_schema(repo):
    """Names, types and defaults of the README's params table are the schema's, row for row."""
    readme = (repo / "README.md").read_text().split("\n## Params file\n")[1].split("\n## ")[0]
    rows = re.findall(r"^\| `([\w.]+)` \| (\w+) \| ([^|]+) \|", readme, flags=re.M)
    table = {name: (kind, default.strip()) for name, kind, default in rows}
    assert set(table) == {*SCHEMA, PLANNER_PARAMS}
    assert table[PLANNER_PARAMS] == ("mapping", "`{}`")
    for name, param in SCHEMA.items():
        kind, default = table[name]
        assert kind == param.type.__name__, name
        expected = "(required)" if param.default is None else f"`{str(param.default).lower() if param.type is bool else param.default}`"
        assert default == expected, name
