"""Fuzzing the CommonRoad importer with mutated recordings: an element removed or repeated, a
number or reference replaced (NaN, inf, negative, huge, garbage), the file cut short or with bits
flipped. The answer is a usable Scenario or one ScenarioError line naming the file; never
another exception (a GEOS error, a networkx NodeNotFound, an AttributeError) or a hang.

Seeds are samples in ../shared/data/commonroad/ (input data, never committed); the tests skip
when that folder or commonroad-io is absent."""

import copy
import logging
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from conftest import REPO
from hypothesis import strategies as st
from mutations import one_line_naming

from advperc_ros.exceptions import ScenarioError

DATA = REPO.parent / "shared" / "data" / "commonroad"
SEEDS = ("USA_US101-1_1_T-1", "USA_Peach-4_3_T-1", "USA_Lanker-1_6_T-1")  # the quickest to read, 2 to 34 vehicles
# hang guard, not a timing: reading a seed takes a tenth of a second
FUZZ = settings(max_examples=40, deadline=20_000, suppress_health_check=[HealthCheck.too_slow])
VALUES = ["nan", "inf", "-inf", "", "x", "-1", "0", "1e308", "-1e308", "1e999", "99999999999999999999", "0.5", "534"]

pytestmark = [
    pytest.mark.skipif(not all((DATA / f"{name}.xml").is_file() for name in SEEDS),
                       reason=f"CommonRoad samples not found at {DATA}"),
    pytest.mark.filterwarnings("ignore"),  # the reader warns about much of what is fed to it here
]


@pytest.fixture(scope="module")
def importer():
    pytest.importorskip("commonroad", reason="commonroad-io is not installed (pip install '.[commonroad]')")
    from advperc_ros.importers.commonroad import import_commonroad

    logging.getLogger("commonroad").setLevel(logging.CRITICAL)
    return import_commonroad


@pytest.fixture(scope="module")
def seeds() -> dict[str, bytes]:
    return {name: (DATA / f"{name}.xml").read_bytes() for name in SEEDS}


def check_usable(imported) -> None:
    scenario = imported.scenario
    assert scenario.problems("imported") == []
    assert math.isfinite(imported.target_speed) and imported.target_speed >= 1.0
    assert all(np.all(np.isfinite(lane.centerline.points)) and lane.width > 0.0 for lane in scenario.lanes)


@st.composite
def mutated(draw, seeds: dict[str, bytes]) -> bytes:
    data = seeds[draw(st.sampled_from(SEEDS))]
    kind = draw(st.sampled_from(["remove", "repeat", "text", "attribute", "cut", "flip"]))
    if kind == "cut":
        return data[: draw(st.integers(0, len(data) - 1))]
    if kind == "flip":
        flipped = bytearray(data)
        for bit in draw(st.lists(st.integers(0, 8 * len(data) - 1), min_size=1, max_size=3)):
            flipped[bit // 8] ^= 1 << bit % 8
        return bytes(flipped)
    root = ET.fromstring(data)
    elements = list(root.iter())
    parents = {child: parent for parent in elements for child in parent}
    if kind in ("remove", "repeat"):
        element = elements[draw(st.integers(1, len(elements) - 1))]
        parent = parents[element]
        if kind == "remove":
            parent.remove(element)
        else:
            parent.insert(list(parent).index(element), copy.deepcopy(element))
    elif kind == "text":
        leaves = [e for e in elements if len(e) == 0 and e.text and e.text.strip()]
        draw(st.sampled_from(leaves)).text = draw(st.sampled_from(VALUES))
    else:
        element = draw(st.sampled_from([e for e in elements if e.attrib]))
        element.attrib[draw(st.sampled_from(sorted(element.attrib)))] = draw(st.sampled_from(VALUES))
    return ET.tostring(root)


@FUZZ
@given(data=st.data())
def test_mutated_recordings_import_usable_or_fail_naming_the_file(importer, seeds, data, tmp_path_factory):
    path = tmp_path_factory.mktemp("cr") / "mutated.xml"
    path.write_bytes(data.draw(mutated(seeds)))
    try:
        imported = importer(path)
    except ScenarioError as exc:
        one_line_naming(exc, str(path))
    else:
        check_usable(imported)


def edited(seeds: dict[str, bytes], tmp_path: Path, edit) -> Path:
    """The first seed with `edit(root)` applied, written to tmp_path."""
    root = ET.fromstring(seeds[SEEDS[0]])
    edit(root)
    path = tmp_path / "edited.xml"
    path.write_bytes(ET.tostring(root))
    return path


def set_text(where: str, text: str):
    def edit(root: ET.Element) -> None:
        root.find(where).text = text
    return edit


def collapse_first_lanelet(root: ET.Element) -> None:
    """Every point of lanelet 534's bounds at the origin."""
    for element in root.find("lanelet").iter():
        if element.tag in ("x", "y"):
            element.text = "0"


def last_state_of_484_at_step_20000(root: ET.Element) -> None:
    root.find("obstacle/trajectory").findall("state")[-1].find("time/exact").text = "20000"


def first_state_of_484_twice(root: ET.Element) -> None:
    trajectory = root.find("obstacle/trajectory")
    trajectory.insert(0, copy.deepcopy(trajectory.find("state")))


def obstacle_484_round(root: ET.Element) -> None:
    shape = root.find("obstacle/shape")
    shape.remove(shape.find("rectangle"))
    shape.append(ET.fromstring("<circle><radius>2</radius></circle>"))


@pytest.mark.parametrize("edit, words", [
    (collapse_first_lanelet, ["'lanelet 534'", "two distinct points"]),
    (set_text("lanelet/leftBound/point/x", "inf"), ["'lanelet 534'", "finite"]),
    (set_text("planningProblem/initialState/position/point/x", "nan"), ["'planningProblem.initialState.position'"]),
    # commonroad-io subtracts 2 pi from these until they are below 2 pi: a hang, were they read
    (set_text("obstacle/initialState/orientation/exact", "1e308"), ["'obstacle 484.orientation'", "1e308"]),
    (set_text("planningProblem/goalState/orientation/intervalEnd", "inf"), ["'planningProblem 482.orientation'"]),
    (lambda root: root.find("lanelet[@id='536']").set("id", "999"), ["'lanelet 534'", "lanelet 536", "does not exist"]),
    (lambda root: root.set("timeStepSize", "inf"), ["'timeStepSize'"]),
    (lambda root: root.set("timeStepSize", "1e300"), ["'timeStepSize'", "1 h"]),  # int64 stamps overflowed
    (last_state_of_484_at_step_20000, ["'dynamicObstacle 484.time_step'", "20000"]),
    (first_state_of_484_twice, ["'dynamicObstacle 484'", "two states at time step 1"]),
    (obstacle_484_round, ["'dynamicObstacle 484.shape'", "rectangle"]),
    (lambda root: root.find("obstacle").set("id", "482"), ["'dynamicObstacle 482'", "planningProblem 482", "unique"]),
])
def test_broken_recordings_name_the_field(importer, seeds, tmp_path, edit, words):
    path = edited(seeds, tmp_path, edit)
    with pytest.raises(ScenarioError) as caught:
        importer(path)
    one_line_naming(caught.value, str(path), *words)


def test_an_obstacle_without_a_trajectory_is_present_at_its_initial_step(importer, seeds, tmp_path):
    """As USA_US101-14_1_T-1 has: the importer failed on it with an AttributeError."""
    path = edited(seeds, tmp_path, lambda r: r.find("obstacle").remove(r.find("obstacle/trajectory")))
    scenario = importer(path).scenario
    slot = list(scenario.agents.ids[0]).index(484)
    assert scenario.agents.valid[:, slot].tolist() == [True] + [False] * (scenario.num_frames - 1)
    assert scenario.agents.x[0, slot] == 8.746


@pytest.mark.parametrize("damage", [lambda data: data.replace(b'encoding="utf-8"', b'encoding="uuf-8"', 1),
                                    lambda data: data[: len(data) // 2]])
def test_unparseable_files_are_named(importer, seeds, tmp_path, damage):
    path = tmp_path / "damaged.xml"
    path.write_bytes(damage(seeds[SEEDS[0]]))
    with pytest.raises(ScenarioError) as caught:
        importer(path)
    one_line_naming(caught.value, str(path), "not a readable CommonRoad scenario")
