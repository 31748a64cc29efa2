"""The one plug-in loader: every registry refuses the same faults with one PluginError line naming the plug-in."""

import pytest

from advperc_ros.core.plugins import PluginKind, load
from advperc_ros.core.search.registry import SEARCH_METHODS
from advperc_ros.exceptions import PluginError
from advperc_ros.exits import expected_failure
from advperc_ros.ros.drive_log import object_layers
from advperc_ros.ros.interfaces.base import Profile
from advperc_ros.ros.interfaces.registry import PROFILES

CLASSES = PluginKind("gadget", {"json": "json:JSONDecoder"}, type, "a class")


def test_a_bundled_name_and_a_module_class_load():
    import json

    assert load("json", CLASSES) is json.JSONDecoder
    assert load("json:JSONEncoder", CLASSES) is json.JSONEncoder
    assert isinstance(load("autoware", PROFILES), Profile)


@pytest.mark.parametrize("target, says", [
    ("nope", "unknown gadget 'nope' (gadgets: json; or module:Class)"),
    ("no_such_module_xyz:Thing", "gadget 'no_such_module_xyz:Thing' cannot be imported: No module named"),
    ("json:Missing", "gadget 'json:Missing' cannot be imported: module 'json' has no attribute 'Missing'"),
    ("json:dumps", "gadget 'json:dumps' is a function, not a class"),
    ("raising_plugin_mod:X", "gadget 'raising_plugin_mod:X': importing raising_plugin_mod raised RuntimeError: boom"),
])
def test_every_fault_is_one_plugin_error_with_exit_code_2(tmp_path, monkeypatch, target, says):
    (tmp_path / "raising_plugin_mod.py").write_text("raise RuntimeError('boom')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(PluginError) as refused:
        load(target, CLASSES)
    assert says in str(refused.value)
    assert expected_failure(refused.value)[1] == 2


def test_a_registry_without_plug_ins_takes_only_its_names():
    with pytest.raises(PluginError, match=r"unknown search method 'json:JSONDecoder' \(search methods: paper, guided\)$"):
        load("json:JSONDecoder", SEARCH_METHODS)


def test_import_bag_reads_what_the_planner_saw_before_detections():
    """The profiles' import ranks give import-bag's order of objects types: predictions, tracks, then detections."""
    assert tuple(object_layers()) == ("autoware_perception_msgs/msg/PredictedObjects",
                                  "autoware_perception_msgs/msg/TrackedObjects", "visualization_msgs/msg/MarkerArray",
                                  "autoware_perception_msgs/msg/DetectedObjects", "vision_msgs/msg/Detection3DArray")
