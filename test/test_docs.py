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
