"""The road as the lane rules see it: each lane a corridor of its width about its centreline.

A point's distance outside a lane is its distance to that corridor (beyond the side, beyond an end,
or both), zero inside; the drivable area is the union of the lanes, and a scenario without lanes
drives in a corridor about its route. Shared by drivable_area, driving_direction and
time_to_collision (which looks sideways only when the ego is not within one lane).
"""

import numpy as np

from advperc_ros.core.parameters import Bounds
from advperc_ros.core.rules.inputs import RuleInputs
from advperc_ros.core.scenario import Lane

ROUTE_WIDTH = 3.5  # m: the road of a scenario without lanes, a corridor about its route
ROUTE_WIDTH_SOURCE = "a lane's width: the bundled scenarios' lanes and a typical urban lane, 3.5 m (m)"
ROUTE_WIDTH_BOUNDS = Bounds(positive=True, high=50.0)  # m: a corridor at most a motorway's width


def road(inputs: RuleInputs, route_width: float) -> tuple[Lane, ...]:
    """The scenario's lanes, or the route as one lane `route_width` wide when it has none."""
    return inputs.lanes or (Lane(id="route", centerline=inputs.route, width=route_width),)


def lane_offsets(points: np.ndarray, lane: Lane) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(station along the lane, signed lateral offset, distance outside its corridor) of points (..., 2)."""
    station, lateral = lane.centerline.project(points)
    beyond_side = np.maximum(np.abs(lateral) - 0.5 * lane.width, 0.0)
    beyond_end = np.maximum(np.maximum(-station, station - lane.centerline.length), 0.0)
    return station, lateral, np.hypot(beyond_side, beyond_end)


def outside_road(points: np.ndarray, lanes: tuple[Lane, ...]) -> np.ndarray:
    """(...) distance of points (..., 2) outside the union of the lanes, 0 inside any."""
    return np.min([lane_offsets(points, lane)[2] for lane in lanes], axis=0)


def containing_lane(points: np.ndarray, lanes: tuple[Lane, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(index of the lane each point (..., 2) lies in, -1 if none; its station there). Where lanes
    overlap, the one whose centreline is nearest."""
    stations, laterals, outside = np.moveaxis(np.array([lane_offsets(points, lane) for lane in lanes]), 1, 0)
    lateral_inside = np.where(outside > 0.0, np.inf, np.abs(laterals))
    index = np.argmin(lateral_inside, axis=0)
    inside = np.isfinite(np.min(lateral_inside, axis=0))
    station = np.take_along_axis(stations, index[None], axis=0)[0]
    return np.where(inside, index, -1), station
