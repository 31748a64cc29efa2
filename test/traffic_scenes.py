"""Scenes for reactive traffic's tests: an ego on a lane with agents recorded at constant speed, and a scripted
ego that brakes to a stop (core tests and the rule monitor's)."""

import numpy as np

from advperc_ros.core.planners.base import Trajectory
from advperc_ros.core.rollout import RolloutConfig
from advperc_ros.core.scenario_spec import build_scenario
from advperc_ros.core.traffic import IDMParameters

CAR = [4.6, 1.9, 1.6]
STRAIGHT = {"id": "east", "centerline": [[-200.0, -1.75], [600.0, -1.75]], "width": 3.5}
REACTIVE = RolloutConfig(traffic=IDMParameters())


class Braking:
    """Brakes to a stop from wherever the ego is at `deceleration` m/s^2 (0: drives on at its speed), along
    the ego's lane: the straight one, or the bend when `lane` is given."""

    def __init__(self, deceleration, lane=None):
        self.deceleration = deceleration
        self.lane = lane

    def reset(self):
        pass

    def plan(self, t, ego, tracks):
        tau = 0.05 * np.arange(161)
        if self.deceleration > 0:
            stop = ego.v / self.deceleration
            d = np.where(tau < stop, ego.v * tau - 0.5 * self.deceleration * tau**2, 0.5 * ego.v * stop)
        else:
            d = ego.v * tau
        if self.lane is None:
            return Trajectory(t=t + tau, x=ego.x + d, y=np.full(tau.size, ego.y), yaw=np.zeros(tau.size))
        s, _ = self.lane.project(np.array([[ego.x, ego.y]]))
        s = float(s[0]) + d + 1e-6 * tau  # strictly increasing stations, even once stopped
        xy = self.lane.position(s)
        return Trajectory(t=t + tau, x=xy[:, 0], y=xy[:, 1], yaw=self.lane.heading(s))


def scene(agents, lane=STRAIGHT, ego_s=200.0, speed=12.0, duration=8.0):
    return build_scenario({"name": "traffic", "dt": 0.1, "duration": duration, "lanes": [lane],
                           "ego": {"route": [lane["id"]], "start_s": ego_s, "speed": speed},
                           "agents": [{"size": CAR, "lane": lane["id"], **agent} for agent in agents]})


