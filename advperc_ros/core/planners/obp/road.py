"""The drivable band around the route, which the prediction prunes with and both stages keep the
ego within: the route's own lane plus the adjacent lane on its left, in either direction."""

from dataclasses import dataclass

import numpy as np

from advperc_ros.core.geometry import Polyline
from advperc_ros.core.scenario import Lane


@dataclass(frozen=True)
class DrivableBand:
    """Lateral offsets of the band's edges from the route, per metre of station."""

    s: np.ndarray
    right: np.ndarray
    left: np.ndarray

    @classmethod
    def around(cls, route: Polyline, lanes: tuple[Lane, ...]) -> "DrivableBand":
        s = np.arange(0.0, route.length + 1.0, 1.0)
        p = route.position(s)
        heading = route.heading(s)
        normal = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
        tangent = np.stack([np.cos(heading), np.sin(heading)], axis=1)
        own_width = np.full(s.shape, 3.5)
        found = np.zeros(s.shape, bool)
        beside_route = []
        for lane in lanes:
            ls, _ = lane.centerline.project(p)
            q = lane.centerline.position(ls) - p
            off = np.einsum("ik,ik->i", q, normal)
            beside = np.abs(np.einsum("ik,ik->i", q, tangent)) < 1.0
            parallel = beside & (np.abs(np.cos(lane.centerline.heading(ls) - heading)) > 0.95)
            own = parallel & (np.abs(off) < 0.2) & ~found
            own_width[own] = lane.width
            found |= own
            beside_route.append((off, parallel, lane.width))
        d_left = own_width / 2.0
        for off, parallel, width in beside_route:
            adjacent = parallel & (np.abs(off - (own_width + width) / 2.0) < 0.5)
            d_left = np.where(adjacent, np.maximum(d_left, off + width / 2.0), d_left)
        return cls(s=s, right=-own_width / 2.0, left=d_left)

    def bounds(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(d_right, d_left): lateral offsets of the band's edges at stations s."""
        return np.interp(s, self.s, self.right), np.interp(s, self.s, self.left)
