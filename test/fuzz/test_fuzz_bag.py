"""Fuzzing the ground-truth bag reader. Whatever the bag holds (an MCAP file cut short or with
bits flipped, a wrong metadata.yaml, topics missing or of another type, NaN and inf, repeated
ids, stamps out of order, empty frames), read_scenario answers the scenario that was written,
nothing lost, or one BagError line naming the bag; never another exception or a hang. And it
refuses exactly the bags that break the contract (test_check_bag spells the contract out)."""

import shutil

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mutations import damaged, one_line_naming
from test_check_bag import DT, LANE, boxes, write_bag

from advperc_ros.core.boxes import BOX_FIELDS
from advperc_ros.core.geometry import wrap_angle
from advperc_ros.exceptions import BagError
from advperc_ros.ros import topics
from advperc_ros.ros.bag import check_ground_truth, read_scenario, read_topics

# hang guard, not a timing: writing and reading one small bag takes milliseconds
FUZZ = settings(max_examples=60, deadline=10_000, suppress_health_check=[HealthCheck.too_slow])
pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")  # arithmetic on NaN and inf written on purpose


def check_usable(scenario) -> None:
    """What a rollout trusts in a scenario it is given."""
    steps = np.diff(scenario.stamps_ns)
    assert scenario.num_frames >= 2 and np.all(steps > 0)
    agents = scenario.agents
    for name in BOX_FIELDS[:-1]:
        assert np.all(np.isfinite(getattr(agents, name)[agents.valid])), name
    for name in ("length", "width", "height"):
        assert np.all(getattr(agents, name)[agents.valid] > 0.0), name
    assert all(np.all(np.isfinite(lane.centerline.points)) and lane.width > 0 for lane in scenario.lanes)
    assert np.all(np.isfinite(scenario.route.points))


@pytest.fixture(scope="module")
def seed_bag(tmp_path_factory):
    """(the MCAP bytes, the metadata.yaml text) of a small valid ground-truth bag."""
    path = write_bag(tmp_path_factory.mktemp("seed") / "seed", frames=[boxes([1, 2]), boxes([2]), boxes([1, 2, 3])])
    return (path / "seed.mcap").read_bytes(), (path / "metadata.yaml").read_text()


def fresh(tmp_path_factory, mcap: bytes, metadata: str):
    path = tmp_path_factory.mktemp("bag") / "seed"
    path.mkdir()
    (path / "seed.mcap").write_bytes(mcap)
    (path / "metadata.yaml").write_text(metadata)
    return path


def read_or_fail_naming(path) -> None:
    """read_scenario, and read_topics deserialising every contract topic (as `advperc score` reads
    odometry), answer or fail with one line naming the bag."""
    try:
        for read in (lambda: check_usable(read_scenario(path)), lambda: read_topics(path, topics.TOPIC_TYPES)):
            try:
                read()
            except BagError as exc:
                one_line_naming(exc, str(path))
    finally:
        shutil.rmtree(path)


@FUZZ
@given(data=st.data())
def test_corrupt_mcap_reads_or_fails_naming_the_bag(seed_bag, data, tmp_path_factory):
    mcap, metadata = seed_bag
    read_or_fail_naming(fresh(tmp_path_factory, data.draw(damaged(mcap, word=8)), metadata))


yaml_values = st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=8) | \
    st.lists(st.integers(), max_size=2) | st.dictionaries(st.text(max_size=4), st.integers(), max_size=2)


def nodes(document, where=()):
    """Every (path, node) of a YAML document, the root first."""
    yield where, document
    children = document.items() if isinstance(document, dict) else enumerate(document) if isinstance(document, list) else ()
    for key, child in children:
        yield from nodes(child, (*where, key))


@st.composite
def wrong_metadata(draw, metadata: str) -> str:
    """metadata.yaml with one node replaced by another YAML value or removed, cut short, or with
    bits flipped."""
    kind = draw(st.sampled_from(["replace", "remove", "text"]))
    if kind == "text":
        return draw(damaged(metadata.encode(), word=8)).decode(errors="replace")
    document = yaml.safe_load(metadata)
    where, _ = draw(st.sampled_from(list(nodes(document))[1:]))
    parent = document
    for key in where[:-1]:
        parent = parent[key]
    if kind == "remove":
        del parent[where[-1]]
    else:
        parent[where[-1]] = draw(yaml_values)
    return yaml.safe_dump(document)


@FUZZ
@given(data=st.data())
def test_wrong_metadata_reads_or_fails_naming_the_bag(seed_bag, data, tmp_path_factory):
    mcap, metadata = seed_bag
    read_or_fail_naming(fresh(tmp_path_factory, mcap, data.draw(wrong_metadata(metadata))))


# ----- contents: the reader against the contract as an oracle -----

SPECIAL = [np.nan, np.inf, -np.inf, 0.0, -1.0]
values = st.floats(-1e5, 1e5) | st.sampled_from(SPECIAL)


@st.composite
def frame(draw) -> dict:
    """Up to three objects whose ids may repeat and whose fields may be NaN, inf, zero or negative."""
    ids = draw(st.lists(st.integers(0, 3), max_size=3))
    out = boxes(ids)
    for name in ("x", "yaw", "vx", "length", "width"):
        if draw(st.booleans()):
            out[name] = np.array([draw(values) for _ in ids], dtype=float)
    return out


@st.composite
def ground_truth(draw) -> dict:
    """The arguments of write_bag: each part valid, missing, malformed or of another type."""
    frames = draw(st.lists(frame(), max_size=4))
    stamps = [k * DT for k in range(len(frames))]
    order = draw(st.sampled_from(["regular", "swap", "repeat", "gap"])) if len(frames) >= 3 else "regular"
    if order == "swap":
        stamps[1], stamps[2] = stamps[2], stamps[1]
    elif order == "repeat":
        stamps[2] = stamps[1]
    elif order == "gap":
        stamps[-1] += DT
    return dict(
        frames=frames, stamps=stamps,
        odometry=draw(st.sampled_from([(5.0, -1.75, 0.0, 8.0), None, (np.nan, 0.0, 0.0, 8.0), (0.0, 0.0, 0.0, np.inf)])),
        route=draw(st.sampled_from([((0.0, -1.75), (100.0, -1.75)), None, ((1.0, 1.0),), ((1.0, 1.0), (1.0, 1.0)),
                                    ((0.0, 0.0), (np.nan, 1.0), (5.0, 5.0))])),
        lanes=draw(st.sampled_from([(LANE,), None, (), (([(0.0, 0.0)], 3.5),), (([(0.0, 0.0), (9.0, 0.0)], np.nan),),
                                    (([(0.0, 0.0), (np.inf, 0.0)], 3.5),), (LANE, ([(0.0, 0.0), (9.0, 0.0)], 0.0))])),
        wrong_type=draw(st.sampled_from([None, None, None, topics.GROUND_TRUTH, topics.ODOMETRY, topics.ROUTE, topics.LANES])),
    )


def keeps_the_contract(case: dict) -> bool:
    """Whether the bag write_bag makes of `case` is a usable ground-truth bag."""
    frames = case["frames"]
    objects_ok = all(
        len(set(f["ids"].tolist())) == len(f["ids"])
        and all(np.all(np.isfinite(f[name])) for name in ("x", "yaw", "vx", "length", "width"))
        and all(np.all(f[name] > 0.0) for name in ("length", "width"))
        for f in frames)
    odometry, route, lanes = case["odometry"], case["route"], case["lanes"]
    route_ok = route is not None and len(route) == 2 and route[0] != route[1] and np.all(np.isfinite(route))
    lanes_ok = lanes is None or all(len(points) >= 2 and np.all(np.isfinite(points)) and width > 0 for points, width in lanes)
    return (len(frames) >= 2 and case["stamps"] == sorted(set(case["stamps"])) and len(set(np.diff(case["stamps"]))) == 1
            and objects_ok and odometry is not None and np.all(np.isfinite(odometry)) and route_ok and lanes_ok
            and case["wrong_type"] in (None, topics.LANES if lanes is None else None))


@FUZZ
@given(case=ground_truth())
def test_reader_keeps_everything_written_or_names_the_bag(case, tmp_path_factory):
    path = write_bag(tmp_path_factory.mktemp("bag") / "gt", **case)
    valid = keeps_the_contract(case)
    try:
        scenario = read_scenario(path)
    except BagError as exc:
        one_line_naming(exc, str(path))
        assert not valid, exc
        assert check_ground_truth(path).problems[0] == str(exc)
        return
    finally:
        shutil.rmtree(path)
    assert valid
    check_usable(scenario)
    agents = scenario.agents
    assert scenario.stamps_ns.tolist() == case["stamps"]
    for k, written in enumerate(case["frames"]):  # nothing lost: every object of every frame, as written
        assert sorted(agents.ids[k][agents.valid[k]].tolist()) == sorted(written["ids"].tolist())
        got = {name: values[np.argsort(agents.ids[k][agents.valid[k]])] for name, values in agents.frame(k).items()}
        order = np.argsort(written["ids"])
        for name in ("x", "y", "length", "width", "height"):
            np.testing.assert_array_equal(got[name], written[name][order], err_msg=name)
        np.testing.assert_allclose(got["vx"], written["vx"][order], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(wrap_angle(got["yaw"] - written["yaw"][order]), 0.0, atol=1e-9)
