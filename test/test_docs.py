"""The documentation stays true: every parameter in the generated params reference, both front-door
commands of the README as CI runs them, and every link of the README to a file that exists."""

import re
import sys

from advperc_ros.params import PLANNER_PARAMS, SCHEMA
from conftest import REPO

sys.path.insert(0, str(REPO / "docs" / "_ext"))
from advperc_docs import markdown_table  # noqa: E402  (docs/_ext is no package: the Sphinx extension's own module)


def _table_rows() -> dict[str, tuple[str, str]]:
    rows = re.findall(r"^\| `([\w.]+)` \| (\w+) \| ([^|]+) \|", markdown_table(), flags=re.M)
    return {name: (kind, default.strip()) for name, kind, default in rows}


def test_every_parameter_is_documented(repo):
    """docs/params.md renders the generated table, and the table has a row for every parameter."""
    page = (repo / "docs" / "params.md").read_text()
    assert "```{params-table}" in page
    assert "advperc_docs" in (repo / "docs" / "conf.py").read_text()
    table = markdown_table()
    for name in [*SCHEMA, PLANNER_PARAMS]:
        assert f"| `{name}` |" in table, name


def test_ci_runs_the_readme_test_command(repo):
    readme = (repo / "README.md").read_text()
    blocks = re.findall(r"```bash\n(.*?)\n```", readme, flags=re.S)
    attack, tests = blocks[0].strip(), blocks[1].strip()
    assert attack.startswith("pip install . && advperc attack config/idm_lane_following.yaml")
    assert tests in (repo / ".ci" / "run").read_text()


def test_params_table_is_the_schema():
    """Names, types, defaults and descriptions of the generated params table are the schema's, row for row."""
    table = _table_rows()
    names = [*SCHEMA]
    names.insert(names.index("planner") + 1, PLANNER_PARAMS)  # the free mapping beside its planner
    assert list(table) == names
    assert table[PLANNER_PARAMS] == ("mapping", "`{}`")
    text = markdown_table()
    for name, param in SCHEMA.items():
        kind, default = table[name]
        assert kind == param.type.__name__, name
        expected = "(required)" if param.default is None else f"`{str(param.default).lower() if param.type is bool else param.default}`"
        assert default == expected, name
        assert param.description.replace("|", "\\|") in text, name


def test_readme_links_name_files_that_exist(repo):
    """The README is read on GitHub and PyPI, outside the Sphinx build that checks the pages' links."""
    readme = (repo / "README.md").read_text()
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", readme)
    assert targets
    for target in targets:
        if "://" not in target:
            assert (repo / target).exists(), target
