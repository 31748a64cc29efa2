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


def with_lead_speed(name: str, speed: float) -> dict:
    """FOLLOW_SPEC with its lead at another constant speed."""
    return {**FOLLOW_SPEC, "name": name, "agents": [{**FOLLOW_SPEC["agents"][0], "speed": speed}, FOLLOW_SPEC["agents"][1]]}


# Attacks that find nothing (IDM target 14 m/s): the lead drives away faster than the ego may, so hiding
# it changes nothing; or the lead is slower, and the ego, blind to it, closes from 15.4 m to 7.4 m in the
# 10 s but never reaches it.
RUNAWAY_LEAD_SPEC = with_lead_speed("runaway_lead", 16.0)
CLOSING_LEAD_SPEC = with_lead_speed("closing_lead", 10.5)


def rotated(spec: dict, degrees: float) -> dict:
    """The same scenario turned about the origin, so its roads run diagonally across the map."""
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    lanes = [{**lane, "centerline": [[c * x - s * y, s * x + c * y] for x, y in lane["centerline"]]}
             for lane in spec["lanes"]]
    return {**spec, "name": f"{spec['name']}_rotated", "lanes": lanes}


# Two slow cars one behind the other in the ego's lane, 1.5 m apart (IDM target 14 m/s). Seeing either
# one, the ego follows it at its headway gap, which keeps it behind the near one; only with both hidden
# does it accelerate into the near one: no single drop collides, the two together do.
PLATOON_SPEC = {
    **FOLLOW_SPEC,
    "name": "platoon",
    "ego": {"route": ["east"], "start_s": 100.0, "speed": 5.0},
    "agents": [
        {"id": 1, "lane": "east", "start_s": 116.6, "speed": 5.0, "size": [4.6, 1.9, 1.6]},  # near
        {"id": 2, "lane": "east", "start_s": 122.7, "speed": 5.0, "size": [4.6, 1.9, 1.6]},  # far
        FOLLOW_SPEC["agents"][1],  # oncoming
    ],
}
