"""The typical-error check on the calibrated default: its samples carry every kind the model has
terms for into the rollouts, and `advperc check-typical` picks the default for the params' kinds."""

import json

import numpy as np
import yaml

from advperc_ros.backends.embedded import Stack
from advperc_ros.cli import main
from advperc_ros.configs import core_configs
from advperc_ros.core.pem import default_pem
from advperc_ros.core.perception_errors import ERROR_KINDS, PAPER_KINDS
from advperc_ros.core.typical import check_typical
from advperc_ros.params import load_params

SCENARIO = "idm_lane_following"


def test_the_check_rolls_out_every_kind_of_the_calibrated_default(repo):
    from advperc_ros.ros.bag import read_scenario

    scenario = read_scenario(repo / "bags" / SCENARIO)
    stack = Stack(scenario, core_configs(load_params(repo / "config" / f"{SCENARIO}.yaml")))
    result = check_typical(scenario, stack.rollout, default_pem(ERROR_KINDS), 3, np.random.default_rng(0))
    assert result.kinds == (*PAPER_KINDS, "velocity", "size", "flip", "ghost")
    assert result.samples == 3 and result.collisions + result.inconclusive <= 3


def test_check_typical_uses_the_default_for_the_params_kinds(repo, tmp_path, capsys):
    document = yaml.safe_load((repo / "config" / f"{SCENARIO}.yaml").read_text())
    document["orchestrator"]["ros__parameters"]["bag"] = str(repo / "bags" / SCENARIO)
    for kinds, expected in (("paper", list(PAPER_KINDS)), ("all", [*PAPER_KINDS, "velocity", "size", "flip", "ghost"])):
        document["orchestrator"]["ros__parameters"]["errors"] = {"kinds": kinds}
        path = tmp_path / f"{kinds}.yaml"
        path.write_text(yaml.safe_dump(document))
        assert main(["check-typical", str(path), "--samples", "1"]) in (0, 1)  # 1: a collision, a finding
        assert json.loads(capsys.readouterr().out)["kinds"] == expected
