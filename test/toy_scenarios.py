"""A small scenario the unit tests share: the ego follows a lead; an oncoming car passes harmlessly."""

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
