"""The params: one typed tree, validated whenever built; and where a relative bag is found."""

import pytest

from advperc_ros.exceptions import ParamsError
from advperc_ros.params import SCHEMA, find_bag, load_params, params_from_values
from advperc_ros.params import install as params_module


def test_every_construction_is_validated(repo):
    params = load_params(repo / "config" / "idm_lane_following.yaml")
    assert params.search.random.steps == 40 and params.get("search.random.steps") == 40
    for change, says in [({"seed": -1}, "'seed' must be at least 0"), ({"seed": 2**70}, "'seed' must be at most"),
                         ({"search.random.proposals": 0}, "at least 1"),
                         ({"search.random.max_offset": float("inf")}, "finite"),
                         ({"search.random.yaw_std": -0.1}, "'search.random.yaw_std' must be at least 0"),
                         ({"ego.width": 0.0}, "'ego.width' must be positive"),
                         ({"tracker.gate": 2}, "must be a float (write 2.0)"),
                         ({"no.such": 1.0}, "unknown parameter 'no.such'")]:
        with pytest.raises(ParamsError, match=says.replace("(", r"\(").replace(")", r"\)")):
            params.with_values(**change)
    assert params.with_values(seed=7).seed == 7 and params.seed == 0  # frozen: a new tree


def test_flat_values_round_trip(repo):
    params = load_params(repo / "config" / "obp_left_turn.yaml")
    again = params_from_values({**params.flat(), "planner_params": dict(params.planner_params)}, None)
    assert again == params and again.config_hash() == params.config_hash()
    assert set(params.flat()) == set(SCHEMA)


def test_an_editable_install_finds_the_bundled_files_in_its_source_tree(repo, tmp_path, monkeypatch):
    """`pip install -e .` installs no share folder: the bundled params then find their bags from any
    working directory, as after `pip install .`."""
    monkeypatch.setattr(params_module.sys, "prefix", str(tmp_path / "venv"))
    assert params_module.package_share() == repo
    monkeypatch.chdir(tmp_path)
    assert find_bag("bags/idm_lane_following", repo / "config" / "idm_lane_following.yaml") == \
        repo / "bags" / "idm_lane_following"
    (tmp_path / "venv" / "share" / "advperc_ros").mkdir(parents=True)  # an installed share comes first
    assert params_module.package_share() == tmp_path / "venv" / "share" / "advperc_ros"


def test_a_relative_bag_is_found_in_one_order(tmp_path, monkeypatch):
    share = tmp_path / "share"
    (share / "bags" / "b").mkdir(parents=True)
    (tmp_path / "configs" / "bags" / "b").mkdir(parents=True)
    monkeypatch.setattr(params_module, "package_share", lambda: share)
    monkeypatch.chdir(tmp_path)
    source = tmp_path / "configs" / "p.yaml"
    assert find_bag("bags/b", source) == source.parent / "bags" / "b"  # next to the params file
    assert find_bag("bags/b", None) == share / "bags" / "b"  # then the package share
    (tmp_path / "bags" / "b").mkdir(parents=True)
    assert find_bag("bags/b", source) == tmp_path.joinpath("bags", "b").relative_to(tmp_path)  # working directory first
    with pytest.raises(ParamsError, match=r"'bag' names 'bags/none', which does not exist \(tried bags/none, "):
        find_bag("bags/none", source)
