"""Fuzzing the checkpoint a resumed attack reads: damaged bytes and random JSON values in a real
checkpoint's lines and params give either exactly the rollouts it holds (the damage changed no value,
or hit only a last line left without its newline, as a kill leaves it: that rollout runs again) or one
ResultsError line naming the checkpoint file, the file left as it was; never a traceback.

Resuming exactly a prefix of the checkpoint's rollouts is what gives the uninterrupted report (the
search is deterministic; test_checkpoint.py and test_resume.py resume such checkpoints to the report),
so each example loads the checkpoint alone instead of running the rest of the attack.
"""

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mutations import damaged
from test_checkpoint import Kept, joined, kept_checkpoint
from test_fuzz_params import one_line_naming

from advperc_ros.backends.resumed import FIELDS, PARAMS, ROLLOUTS, Checkpoint, Stored, checkpoint_folder
from advperc_ros.configs import core_configs
from advperc_ros.core.scenario import Scenario
from advperc_ros.exceptions import ResultsError
from advperc_ros.params import AttackParams, load_params
from advperc_ros.ros.bag import read_scenario

FUZZ = settings(max_examples=40, deadline=5000, suppress_health_check=[HealthCheck.too_slow])  # deadline: hang guard

scalars = st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=8)
json_values = st.recursive(scalars, lambda inner: st.lists(inner, max_size=3)
                           | st.dictionaries(st.text(max_size=6), inner, max_size=3), max_leaves=8)


@pytest.fixture(scope="module")
def kept(tmp_path_factory) -> Kept:
    return kept_checkpoint(tmp_path_factory.mktemp("kept"))


@dataclass(frozen=True)
class Attack:
    """The kept checkpoint's attack: its params, scenario, and the rollouts a resume takes from it."""

    params: AttackParams
    scenario: Scenario
    rollouts: list[Stored]


@pytest.fixture(scope="module")
def attack(kept, tmp_path_factory) -> Attack:
    params, scenario = load_params(kept.params), read_scenario(REPO / "bags" / "idm_lane_following")
    output = tmp_path_factory.mktemp("whole") / "out"
    shutil.copytree(kept.checkpoint, checkpoint_folder(output))
    checkpoint = Checkpoint(output, core_configs(params).canonical, scenario, resume=True)
    checkpoint.close(finished=False)
    assert len(checkpoint.done) == len(kept.lines)
    return Attack(params, scenario, checkpoint.done)


def load(kept: Kept, attack: Attack, folder: Path, name: str, data: bytes) -> list[Stored] | None:
    """The rollouts a resume takes from the kept checkpoint with `data` for its file `name`; None when it
    is refused, which must be in one line naming that file, and leave it as it was."""
    output = folder / "out"
    shutil.copytree(kept.checkpoint, checkpoint_folder(output))
    path = checkpoint_folder(output) / name
    path.write_bytes(data)
    try:
        checkpoint = Checkpoint(output, core_configs(attack.params).canonical, attack.scenario, resume=True)
    except ResultsError as exc:
        one_line_naming(exc, path)
        assert path.read_bytes() == data, "a refused checkpoint was changed"
        return None
    checkpoint.close(finished=False)
    return checkpoint.done


def same(loaded: list[Stored], expected: list[Stored]) -> bool:
    return len(loaded) == len(expected) and all(
        a.errors == b.errors and np.array_equal(a.result.ego, b.result.ego)
        and np.array_equal(a.result.distances, b.result.distances) and a.result.inconclusive == b.result.inconclusive
        and a.result.planner_failures == b.result.planner_failures for a, b in zip(loaded, expected))


def unchanged_or_one_line(kept: Kept, attack: Attack, folder: Path, name: str, data: bytes) -> None:
    """Every line whole: the checkpoint loads with every rollout it holds, or is refused in one line."""
    loaded = load(kept, attack, folder, name, data)
    assert loaded is None or same(loaded, attack.rollouts)


@FUZZ
@given(data=st.data())
def test_damaged_bytes_in_a_line_load_unchanged_or_fail_in_one_line(tmp_path_factory, kept, attack, data):
    lines = kept.lines
    n = data.draw(st.integers(0, len(lines) - 1))
    lines[n] = data.draw(damaged(lines[n], 8, arbitrary=True))
    unchanged_or_one_line(kept, attack, tmp_path_factory.mktemp("fuzz"), ROLLOUTS, joined(lines))


@FUZZ
@given(data=st.data())
def test_a_checkpoint_cut_anywhere_loads_its_whole_lines(tmp_path_factory, kept, attack, data):
    """A kill mid-write: what was written whole is kept, the line cut short runs again."""
    rollouts = (kept.checkpoint / ROLLOUTS).read_bytes()
    cut = rollouts[: data.draw(st.integers(0, len(rollouts)))]
    loaded = load(kept, attack, tmp_path_factory.mktemp("fuzz"), ROLLOUTS, cut)
    assert loaded is not None and same(loaded, attack.rollouts[: len(loaded)])
    assert len(loaded) in (cut.count(b"\n"), cut.count(b"\n") + 1)  # + 1: cut just before the last newline


def replaced(line: dict, data) -> object:
    """`line` with a random JSON value in place of it whole, of one field, or of one row or cell."""
    where = data.draw(st.sampled_from(["line", "field", "ego row", "ego cell", "distances row", "distances cell"]))
    value = data.draw(json_values)
    if where == "line":
        return value
    if where == "field":
        line[data.draw(st.sampled_from(FIELDS))] = value
        return line
    table = line[where.split()[0]]
    k = data.draw(st.integers(0, len(table) - 1))
    if where.endswith("row"):
        table[k] = value
    else:
        table[k][data.draw(st.integers(0, len(table[k]) - 1))] = value
    return line


@FUZZ
@given(data=st.data())
def test_random_json_values_in_a_line_load_unchanged_or_fail_in_one_line(tmp_path_factory, kept, attack, data):
    lines = kept.lines
    n = data.draw(st.integers(0, len(lines) - 1))
    lines[n] = json.dumps(replaced(json.loads(lines[n]), data)).encode()
    unchanged_or_one_line(kept, attack, tmp_path_factory.mktemp("fuzz"), ROLLOUTS, joined(lines))


@FUZZ
@given(data=st.data())
def test_damaged_params_load_unchanged_or_fail_in_one_line(tmp_path_factory, kept, attack, data):
    params = data.draw(damaged((kept.checkpoint / PARAMS).read_bytes(), 8, arbitrary=True))
    unchanged_or_one_line(kept, attack, tmp_path_factory.mktemp("fuzz"), PARAMS, params)
