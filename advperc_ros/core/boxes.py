"""Boxes per frame as padded (frames x slots) arrays: ground truth, detections and tracks alike.

One type for all three keeps message conversion and metrics in one place. For ground truth and
injected detections slot j is agent j in every frame; for tracks a slot is just a slot.
"""

from dataclasses import dataclass, fields, replace

import numpy as np

# any position (m), size (m), speed (m/s) or angle of a scene is far below this; beyond it the geometry's
# squares and products overflow or lose every digit that matters
MAGNITUDE_BOUND = 1e6
# m around the ego within which a car counts: the nuScenes class range of cars. The metrics filter by it, the
# perception error model draws its ghosts within it and the search's moves pick the cars near the ego by it
CLASS_RANGE = 50.0

BOX_FIELDS = ("x", "y", "yaw", "vx", "vy", "length", "width", "height", "score")


@dataclass(frozen=True)
class BoxSequence:
    """Boxes over frames in fixed slots (frames x slots arrays, `valid` marks presence): ground truth,
    detections and tracks share this one layout, so injecting errors, scoring and rule checks are
    array operations over a whole scenario rather than loops over objects."""

    ids: np.ndarray  # (F, M) int64
    valid: np.ndarray  # (F, M) bool
    x: np.ndarray  # (F, M) float64, metres in frame `map`
    y: np.ndarray
    yaw: np.ndarray  # rad
    vx: np.ndarray  # m/s
    vy: np.ndarray
    length: np.ndarray  # m
    width: np.ndarray
    height: np.ndarray
    score: np.ndarray  # detection confidence; nan for ground truth

    @property
    def shape(self) -> tuple[int, int]:
        return self.valid.shape

    @classmethod
    def empty(cls, num_frames: int, slots: int) -> "BoxSequence":
        shape = (num_frames, slots)
        floats = {name: np.zeros(shape) for name in BOX_FIELDS}
        floats["score"][:] = np.nan
        return cls(ids=np.zeros(shape, dtype=np.int64), valid=np.zeros(shape, dtype=bool), **floats)

    @classmethod
    def stack(cls, frames: list[dict[str, np.ndarray]]) -> "BoxSequence":
        """Pad per-frame dicts of 1-D arrays (keys: ids and BOX_FIELDS) into one sequence."""
        slots = max((len(frame["ids"]) for frame in frames), default=0)
        out = cls.empty(len(frames), slots)
        for k, frame in enumerate(frames):
            m = len(frame["ids"])
            out.valid[k, :m] = True
            out.ids[k, :m] = frame["ids"]
            for name in BOX_FIELDS:
                getattr(out, name)[k, :m] = frame.get(name, np.nan if name == "score" else 0.0)
        return out

    def select(self, rows: np.ndarray | slice) -> "BoxSequence":
        """The frames `rows` (indices or a slice)."""
        return replace(self, **{f.name: getattr(self, f.name)[rows] for f in fields(self)})

    def select_slots(self, columns: np.ndarray) -> "BoxSequence":
        """The slots `columns` (indices), in that order."""
        return replace(self, **{f.name: getattr(self, f.name)[:, columns] for f in fields(self)})

    def frames(self, stop: int) -> "BoxSequence":
        """The first `stop` frames."""
        return self.select(slice(0, stop))

    def frame(self, k: int) -> dict[str, np.ndarray]:
        """Valid boxes of frame k as a dict of 1-D arrays."""
        mask = self.valid[k]  # the row, then the mask: half the cost of [k, mask]
        return {name: getattr(self, name)[k][mask] for name in ("ids", *BOX_FIELDS)}

    def every_frame(self) -> list[dict[str, np.ndarray]]:
        """frame(k) of every frame, for a fraction of the cost (a rollout asks every frame): each
        field masked once, in frame order, then cut into frames."""
        ends = np.cumsum(np.count_nonzero(self.valid, axis=1)).tolist()
        boxes = {name: getattr(self, name)[self.valid] for name in ("ids", *BOX_FIELDS)}
        return [{name: values[start:end] for name, values in boxes.items()} for start, end in zip([0, *ends], ends)]

    def first_invalid_field(self) -> tuple[str, int, int] | None:
        """(field, frame, slot) of the first valid entry that is not finite, beyond `MAGNITUDE_BOUND`
        (1e300 is finite, and squared in a distance it is not), or a size not positive, if any."""
        for name in BOX_FIELDS[:-1]:
            values = getattr(self, name)
            bad = self.valid & ~(np.abs(values) <= MAGNITUDE_BOUND)
            if name in ("length", "width", "height"):
                bad |= self.valid & (values <= 0.0)
            if bad.any():
                k, j = np.argwhere(bad)[0]
                return name, int(k), int(j)
        return None


def in_range(boxes: BoxSequence, ego_xy: np.ndarray) -> np.ndarray:
    """Which boxes count (frames x slots): present and within the nuScenes class range of the ego,
    as the devkit filters both ground truth and predictions before matching."""
    dist = np.hypot(boxes.x - ego_xy[:, :1], boxes.y - ego_xy[:, 1:2])
    return boxes.valid & (dist < CLASS_RANGE)
