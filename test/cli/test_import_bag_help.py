"""`advperc import-bag --help` names the message types the importer reads, per interface profile: a team
with an Autoware or vision_msgs log learns from the help alone whether its bag can be imported."""

import pytest

from advperc_ros.cli import build_parser
from advperc_ros.ros.interfaces.registry import BUNDLED


@pytest.fixture
def help_text(capsys) -> str:
    with pytest.raises(SystemExit) as exit_:
        build_parser().parse_args(["import-bag", "--help"])
    assert exit_.value.code == 0
    return capsys.readouterr().out


def _profile_line(text: str, profile: str) -> str:
    return next(line.strip() for line in text.splitlines() if line.strip().startswith(f"{profile}: "))


def test_every_profile_has_its_line(help_text):
    for profile in BUNDLED:
        assert _profile_line(help_text, profile)


def test_autoware_types_are_named(help_text):
    assert _profile_line(help_text, "autoware") == ("autoware: detections autoware_perception_msgs/msg/DetectedObjects, "
                                                    "tracks autoware_perception_msgs/msg/PredictedObjects")
    assert "tracks autoware_perception_msgs/msg/TrackedObjects" in _profile_line(help_text, "autoware_tracked")


def test_vision_msgs_and_our_own_types_are_named(help_text):
    assert "detections vision_msgs/msg/Detection3DArray" in _profile_line(help_text, "vision_msgs")
    assert _profile_line(help_text, "advperc") == ("advperc: detections visualization_msgs/msg/MarkerArray, "
                                                   "tracks visualization_msgs/msg/MarkerArray")


def test_ego_and_road_types_are_named(help_text):
    assert "ego (--odometry): nav_msgs/msg/Odometry" in help_text
    assert "/map/lanes (visualization_msgs/msg/MarkerArray)" in help_text
    assert "/ego/route (nav_msgs/msg/Path)" in help_text
