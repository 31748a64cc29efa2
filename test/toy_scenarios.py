"""Small scenarios the unit tests share: the ego follows a lead; an oncoming car passes harmlessly."""

import math

FOLLOW_SPEC = {
    "name": "follow",
    "dt": 0.1,
    "duration": 10.0,
    "lanes": [
        {"id": "east", "centerline": [[-100.0, -1.75], [500.0, -1.75]], "width": 3.5},
        {"id": "west", "centerline": [[500.0, 1.75], [-100.0, 1.75]], "width": 3.5},
    ],
    "ego": {"route": ["east"], "start_s": 100.0, "speed": 8.0},
    "agents": [
        {"id": 1, "lane": "east", "start_s": 120.0, "speed": 8.0, "size": [4.6, 1.9, 1.6]},  # lead
        {"id": 7, "lane": "west", "start_s": 250.0, "speed": 10.0, "size": [4.4, 1.8, 1.5]},  # oncoming
    ],
}

# The lead drives away faster than the ego may (IDM target 14 m/s): hiding any one car never makes the
# ego collide, so an attack finds nothing.
RUNAWAY_LEAD_SPEC = {
    **FOLLOW_SPEC,
    "name": "runaway_lead",
    "agents": [{**FOLLOW_SPEC["agents"][0], "speed": 16.0}, FOLLOW_SPEC["agents"][1]],
}


def rotated(spec: dict, degrees: float) -> dict:
    """The same scenario turned about the origin, so its roads run diagonally across the map."""
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    lanes = [{**lane, "centerline": [[c * x - s * y, s * x + c * y] for x, y in lane["centerline"]]}
             for lane in spec["lanes"]]
    return {**spec, "name": f"{spec['name']}_rotated", "lanes": lanes}
