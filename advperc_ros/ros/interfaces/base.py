"""What an interface profile is; this module imports no profile.

The graph's nodes keep their own per-frame data (boxes as dicts of 1-D arrays, `core.boxes.BOX_FIELDS`
and `ids`; plans as `core.planners.base.Trajectory`) and meet a team's nodes only at the layers a
profile names. A profile is data plus four conversions; which one runs is a parameter
(`graph.interface`), never a branch in a node.
"""

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from advperc_ros.core.boxes import BOX_FIELDS
from advperc_ros.core.planners.base import Trajectory
from advperc_ros.exceptions import MessageError

Cdr = bytes | memoryview  # as `advperc_ros.ros.cdr.Cdr`, which this module does not import (it loads rosbags' types)
Objects = dict[str, np.ndarray]
"""One frame's boxes: `ids` (int64) and every `core.boxes.BOX_FIELDS` as 1-D arrays, sorted by id."""


def objects_from_rows(ids: list[int], rows: Sequence[tuple[float, ...]], where: str) -> Objects:
    """Boxes read from a message (one row of BOX_FIELDS per object, in message order) as `Objects`,
    sorted by id; an id twice is a MessageError (one id is one object, as the MarkerArray reader holds)."""
    if len(set(ids)) != len(ids):
        duplicate = next(i for i in ids if ids.count(i) > 1)
        raise MessageError(f"{where}: field 'id': object {duplicate} appears twice")
    order = np.argsort(np.asarray(ids, dtype=np.int64), kind="stable")
    columns = np.array(rows, dtype=float).reshape(-1, len(BOX_FIELDS))[order].T.copy()
    objects = dict(zip(BOX_FIELDS, columns))
    objects["ids"] = np.asarray(ids, dtype=np.int64)[order]
    return objects


@dataclass(frozen=True)
class ObjectsLayer:
    """A layer of boxes (detections or tracked objects) on one topic in one message type.

    `encode(objects, stamp_ns, kind)` gives the CDR payload (`kind` is ground_truth, perception or
    tracking: only a display type uses it); `decode(data, where)` gives (its stamp, or None when the
    message carries none; the boxes), raising `MessageError` prefixed by `where` on bad input.
    `import_rank` orders the types import-bag reads from a team's drive log when it holds several:
    lower first, so what the planner saw (predictions, tracks) wins over detections."""

    topic: str
    msgtype: str
    encode: Callable[[Objects, int, str], bytes]
    decode: Callable[[Cdr, str], tuple[int | None, Objects]]
    import_rank: int
    carries_velocity: bool = True  # False: the type has no velocity field, so decoded vx, vy are 0
    # a type naming objects by UUID: a message's ids (as `decode` gives them) -> their UUIDs (hex), which
    # import-bag keeps in the bags so a team's own ids travel with its attacks; None: the ids are the ids
    uuids: Callable[[Cdr, str], dict[int, str]] | None = None


@dataclass(frozen=True)
class PlanLayer:
    """The plan on one topic in one message type.

    `encode(plan, stamp_ns)` gives the CDR payload of a plan computed at `stamp_ns`;
    `decode(data, first_stamp_ns, ego_xy, where)` gives (its stamp, the plan with times in seconds
    since the scenario's first stamp). `ego_xy` is the ego's position when the plan was asked for:
    a type whose points may carry no times (Autoware's, sampled by distance) is timed from it."""

    topic: str
    msgtype: str
    encode: Callable[[Trajectory, int], bytes]
    decode: Callable[[Cdr, int, tuple[float, float], str], tuple[int, Trajectory]]


@dataclass(frozen=True)
class Profile:
    """The types and topic names of one stack: what the injector publishes as detections, what the
    tracker reads and publishes, what a planner reads (tracks and the ego's odometry, always
    nav_msgs/Odometry, and its acceleration where the stack has a topic for it) and publishes.
    Topic names are the stack's own, so a team's node runs unchanged (ROS remapping covers the rest).
    `message_types` are the stack's own types the Jazzy typestore lacks (`.msg` text per type name),
    which the profile's module registers as it loads (`ros.cdr.register_types`)."""

    name: str
    description: str
    detections: ObjectsLayer
    tracks: ObjectsLayer
    plan: PlanLayer
    ego_topic: str
    acceleration_topic: str | None = None  # where the stack reads the ego's acceleration, if it does
    transforms_topic: str | None = None  # where the stack reads map -> base_link (tf2_msgs/TFMessage), if it does
    message_types: Mapping[str, str] = field(default_factory=dict)
