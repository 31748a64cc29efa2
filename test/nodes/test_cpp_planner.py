"""A C++ team's planner node, as docs/stacks.md shows the way in: examples/cpp_planner (an ament_cmake
package, one rclcpp node on a timer under use_sim_time, PredictedObjects in, Trajectory out, nothing of
ours linked) built with colcon in the workspace beside our package, run with `ros2 run` and attacked
through `ros2 launch ... planner:=external interface:=autoware drive:=clock`, as test_ros2.py attacks its
Python counterpart, examples/autoware_planner.py.

Needs ROS 2 with the Autoware messages, colcon, CMake and a C++ compiler: without them it skips, saying
which is missing; in CI's second run (ADVPERC_REQUIRE_ROS=1) a missing one fails it.
"""

import subprocess
import time
from pathlib import Path

import pytest
import test_ros2
from conftest import need_program, need_ros
from test_ros2 import TIMEOUT, _attack_a_timer_planner_to_a_collision

workspace = test_ros2.workspace  # the fixture: a colcon workspace of this module's own, our package built into it

PACKAGE = "src/advperc_ros/examples/cpp_planner"  # nested in our package, so colcon's own crawl does not see it


@pytest.fixture(scope="module")
def cpp_workspace(workspace) -> Path:
    """The colcon workspace with our package and, built into it as docs/stacks.md says, the C++ planner."""
    need_ros("autoware_planning_msgs")  # the kit's overlay of the driving stacks' messages
    need_program("cmake")
    need_program("c++")
    started = time.monotonic()
    build = subprocess.run(["colcon", "build", "--base-paths", PACKAGE], cwd=workspace, capture_output=True,
                           text=True, timeout=TIMEOUT)
    assert build.returncode == 0, build.stdout[-4000:] + build.stderr[-2000:]
    # colcon shows a package's compiler warnings under `--- stderr:`: the example builds clean with -Wall -Wextra
    assert "--- stderr: cpp_planner" not in build.stdout, build.stdout[-4000:]
    print(f"colcon build of cpp_planner: {time.monotonic() - started:.1f} s")
    return workspace


def test_the_cpp_planner_on_a_timer_is_attacked_to_a_collision_through_ros2_launch(cpp_workspace, ros_domain,
                                                                                   tmp_path):
    """The rclcpp node, started with `ros2 run`, attacked as the Python example is: every rollout conclusive
    (its guard condition plans the restart each rollout starts with, a jump of the clock back), a collision
    found and reproduced (its single-threaded executor takes /clock itself, so each tick plans on its own
    frame), the report naming the node and the version it announces."""
    _attack_a_timer_planner_to_a_collision(cpp_workspace, ros_domain, tmp_path,
                                           "ros2 run cpp_planner cpp_autoware_planner", "/cpp_autoware_planner",
                                           "cpp-acc-0.1")
