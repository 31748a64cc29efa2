"""The error tensor e and the attack function I(y, e).

The paper's e holds, per frame and agent, a world-frame position offset, a yaw offset and a
false-negative flag; size and velocity stay true. Real detectors fail in more ways, each scored by
nuScenes' metrics, so e may also hold, each only when its kind is enabled (`ERROR_KINDS`): a velocity
error, a length and width scale, a heading flip, a latency (the detection shows the agent as it was
some frames earlier) and, per frame, ghost detections no agent explains. A kind that is off has no
array at all, so a tensor of the paper's kinds is the paper's, to the bit, in memory, on disk and in
every digest.
"""

from dataclasses import dataclass, fields, replace
from functools import lru_cache

import numpy as np

from advperc_ros.core.boxes import BOX_FIELDS, BoxSequence
from advperc_ros.core.geometry import wrap_angle

CONFIDENCE_SEED = 20240617
GHOST_CONFIDENCE_SEED = 20261127

PAPER_KINDS = ("position", "yaw", "drop")  # the paper's error space: its arrays are always there
PAPER_ARRAYS = ("dx", "dy", "dyaw", "fn")
# the kinds beyond the paper and the optional arrays each adds to the tensor (per frame and agent, or for
# `ghost` per frame and ghost slot)
EXTENDED_KINDS: dict[str, tuple[str, ...]] = {
    "velocity": ("dvx", "dvy"),
    "size": ("length_scale", "width_scale"),
    "flip": ("flip",),
    "latency": ("latency",),
    "ghost": ("ghost_on", "ghost_x", "ghost_y", "ghost_yaw", "ghost_vx", "ghost_vy"),
}
ERROR_KINDS = PAPER_KINDS + tuple(EXTENDED_KINDS)
# what an optional array holds when nothing is wrong, and its dtype
NEUTRAL: dict[str, tuple[object, type]] = {
    "dvx": (0.0, np.float64), "dvy": (0.0, np.float64), "length_scale": (1.0, np.float64),
    "width_scale": (1.0, np.float64), "flip": (False, np.bool_), "latency": (0, np.int64),
    "ghost_on": (False, np.bool_), "ghost_x": (0.0, np.float64), "ghost_y": (0.0, np.float64),
    "ghost_yaw": (0.0, np.float64), "ghost_vx": (0.0, np.float64), "ghost_vy": (0.0, np.float64),
}
# a ghost is a car no agent explains: a passenger car's box (m), whatever the scenario's cars are
GHOST_LENGTH, GHOST_WIDTH, GHOST_HEIGHT = 4.5, 1.8, 1.5
# a ghost's confidence ranks above this share of the real detections' (`ghost_scores`): the median, neither
# the cheapest false positive (below every true one) nor the dearest
GHOST_CONFIDENCE_QUANTILE = 0.5


def parse_error_kinds(text: str) -> tuple[str, ...]:
    """The kinds `errors.kinds` names: `paper`, `all`, or a comma-separated list of kind names, in
    `ERROR_KINDS` order; a ValueError naming what is wrong otherwise. The paper's kinds are always on:
    the search finds its failure mode with drops (Algorithm 1) and moves by offsets, so a list names
    the extended kinds added to them (naming a paper kind too is allowed and changes nothing)."""
    if text == "paper":
        return PAPER_KINDS
    if text == "all":
        return ERROR_KINDS
    names = [name.strip() for name in text.split(",")]
    unknown = [name for name in names if name not in ERROR_KINDS]
    if unknown or not text.strip():
        raise ValueError(f"unknown error kind {unknown[0] if unknown else text!r}: 'paper', 'all' or a comma-separated "
                         f"list of {', '.join(ERROR_KINDS)}")
    return tuple(kind for kind in ERROR_KINDS if kind in names or kind in PAPER_KINDS)


@dataclass(frozen=True)
class ErrorSpace:
    """Which errors the search may make and how large: the kinds on (`ERROR_KINDS` order) and the bounds
    of the extended ones. The paper's kinds are bounded by the search's own moves (a push stays within a
    match threshold, a drop is a drop)."""

    kinds: tuple[str, ...] = PAPER_KINDS
    max_speed_error: float = 5.0  # m/s, of a detection's velocity in each axis
    min_scale: float = 0.5  # of a detection's length and width
    max_scale: float = 2.0
    max_latency: int = 5  # frames
    ghosts: int = 2  # slots per frame

    def blank(self, num_frames: int, num_agents: int) -> "PerceptionErrors":
        """No error, with an array for every kind on."""
        return PerceptionErrors.none(num_frames, num_agents, self.kinds, self.ghosts)


@dataclass(frozen=True)
class PerceptionErrors:
    """The error tensor e: per frame and agent a position and yaw offset and a dropped flag (the
    paper's), and the arrays of whatever extended kinds are on (None when off). Everything the search
    changes is in it and nothing else, so an attack is this tensor; it is saved with the results
    (attack_errors.npz) and replayed from there."""

    dx: np.ndarray  # (T, N) metres
    dy: np.ndarray  # (T, N) metres
    dyaw: np.ndarray  # (T, N) rad
    fn: np.ndarray  # (T, N) bool, True drops the detection
    dvx: np.ndarray | None = None  # (T, N) m/s added to the true velocity, world frame
    dvy: np.ndarray | None = None
    length_scale: np.ndarray | None = None  # (T, N) factor on the true length
    width_scale: np.ndarray | None = None
    flip: np.ndarray | None = None  # (T, N) bool, the heading turned by pi
    latency: np.ndarray | None = None  # (T, N) int, frames the detection lags behind the agent
    ghost_on: np.ndarray | None = None  # (T, G) bool, ghost slot g shows a car at frame k
    ghost_x: np.ndarray | None = None  # (T, G) metres, frame `map`
    ghost_y: np.ndarray | None = None
    ghost_yaw: np.ndarray | None = None  # rad
    ghost_vx: np.ndarray | None = None  # m/s
    ghost_vy: np.ndarray | None = None

    @classmethod
    def none(cls, num_frames: int, num_agents: int, kinds: tuple[str, ...] = PAPER_KINDS,
             ghosts: int = 0) -> "PerceptionErrors":
        """No error at all, with the arrays of the extended `kinds` (`ghosts` slots per frame)."""
        shape = (num_frames, num_agents)
        out = cls(np.zeros(shape), np.zeros(shape), np.zeros(shape), np.zeros(shape, dtype=bool))
        for kind in kinds:
            out = out.with_kind(kind, ghosts)
        return out

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> "PerceptionErrors":
        """The tensor these named arrays make (a file's, a message's), checked: the paper's four and whole
        kinds only, one frames x agents shape (ghosts: frames x slots), booleans where flags are, finite
        numbers, whole latencies of at least 0 frames, scales above 0. A ValueError names the first field
        that is wrong."""
        unknown = sorted(set(arrays) - {f.name for f in fields(cls)})
        if unknown:
            raise ValueError(f"field '{unknown[0]}' is no part of an error tensor")
        for kind, names in {"position, yaw and drop": PAPER_ARRAYS, **EXTENDED_KINDS}.items():
            present = [name for name in names if name in arrays]
            if (present and len(present) < len(names)) or (kind.startswith("position") and not present):
                missing = next(name for name in names if name not in arrays)
                raise ValueError(f"field '{missing}' is missing ({kind} needs {', '.join(names)})")
        shape = np.shape(arrays["fn"])
        ghost_shape = np.shape(arrays["ghost_on"]) if "ghost_on" in arrays else None
        checked: dict[str, np.ndarray] = {}
        for name, raw in arrays.items():
            array = np.asarray(raw)
            wanted = ghost_shape if name.startswith("ghost_") else shape
            if array.ndim != 2 or array.shape != wanted or (ghost_shape is not None and ghost_shape[0] != shape[0]):
                slots = "ghost slots" if name.startswith("ghost_") else "agents"
                raise ValueError(f"field '{name}' must be a frames x {slots} array of the tensor's {shape[0]} frames")
            dtype = np.bool_ if name == "fn" else NEUTRAL[name][1] if name in NEUTRAL else np.float64
            if (dtype is np.bool_ and array.dtype.kind != "b") or (dtype is np.int64 and array.dtype.kind not in "iu"):
                raise ValueError(f"field '{name}' must hold {'booleans' if dtype is np.bool_ else 'whole numbers'}")
            if dtype is np.float64 and (array.dtype.kind not in "fiu" or not np.isfinite(array).all()):
                raise ValueError(f"field '{name}' must hold finite numbers")
            if (name == "latency" and (array < 0).any()) or (name.endswith("_scale") and not (array > 0).all()):
                raise ValueError(f"field '{name}' must be {'at least 0' if name == 'latency' else 'above 0'} everywhere")
            checked[name] = array.astype(dtype)
        return cls(**checked)

    @property
    def shape(self) -> tuple[int, int]:
        return self.fn.shape

    @property
    def ghost_slots(self) -> int:
        return 0 if self.ghost_on is None else self.ghost_on.shape[1]

    @property
    def kinds(self) -> tuple[str, ...]:
        """The paper's kinds and the extended ones this tensor has arrays for."""
        return PAPER_KINDS + tuple(kind for kind, names in EXTENDED_KINDS.items() if getattr(self, names[0]) is not None)

    def arrays(self) -> dict[str, np.ndarray]:
        """Every array it has, by name, in the fixed field order (what files, messages and digests hold)."""
        return {f.name: value for f in fields(self) if (value := getattr(self, f.name)) is not None}

    def with_kind(self, kind: str, ghosts: int = 0) -> "PerceptionErrors":
        """These errors with the arrays of `kind`, neutral where they were absent (itself if present)."""
        names = EXTENDED_KINDS.get(kind, ())
        if not names or getattr(self, names[0]) is not None:
            return self
        shape = (self.shape[0], ghosts) if kind == "ghost" else self.shape
        return replace(self, **{name: np.full(shape, *NEUTRAL[name]) for name in names})

    def copy(self) -> "PerceptionErrors":
        return PerceptionErrors(**{name: array.copy() for name, array in self.arrays().items()})

    def with_drop(self, agent: int, start: int, end: int) -> "PerceptionErrors":
        """These errors plus agent `agent` dropped on frames start..end inclusive."""
        out = self.copy()
        out.fn[start : end + 1, agent] = True
        return out

    def perceive_perfectly(self, first: int, last: int, slot: int) -> None:
        """In place: agent `slot` detected without any error on frames first..last inclusive."""
        rows = slice(first, last + 1)
        self.fn[rows, slot] = False
        self.dx[rows, slot] = self.dy[rows, slot] = self.dyaw[rows, slot] = 0.0
        for kind, names in EXTENDED_KINDS.items():
            for name in names if kind != "ghost" else ():
                array = getattr(self, name)
                if array is not None:
                    array[rows, slot] = NEUTRAL[name][0]

    def attacked(self) -> np.ndarray:
        """(frames x agents) the object-frames shown other than they are: dropped, displaced, turned,
        lagging, resized or wrongly fast (a yaw error alone is noise, as the paper's proposals add it)."""
        out = self.fn | (self.dx != 0) | (self.dy != 0)
        for kind, names in EXTENDED_KINDS.items():
            for name in names if kind != "ghost" else ():
                array = getattr(self, name)
                if array is not None:
                    out |= array != NEUTRAL[name][0]
        return out

    def used_kinds(self, frames: int) -> tuple[str, ...]:
        """The kinds whose errors show in the first `frames` frames (a dropped detection shows no other)."""
        rows = slice(0, frames)
        shown = ~self.fn[rows]
        used = {"position": bool(((self.dx[rows] != 0) | (self.dy[rows] != 0))[shown].any()),
                "yaw": bool((self.dyaw[rows] != 0)[shown].any()), "drop": bool(self.fn[rows].any()),
                "ghost": self.ghost_on is not None and bool(self.ghost_on[rows].any())}
        for kind, names in EXTENDED_KINDS.items():
            arrays = [getattr(self, name) for name in names]
            if kind != "ghost" and arrays[0] is not None:
                used[kind] = any(bool((array[rows] != NEUTRAL[name][0])[shown].any()) for name, array in zip(names, arrays))
        return tuple(kind for kind in ERROR_KINDS if used.get(kind))

    def without(self, kind: str) -> "PerceptionErrors":
        """A copy with no error of `kind` (a dropped detection shown again, without an offset)."""
        out = self.copy()
        if kind == "position":
            out.dx[:] = out.dy[:] = 0.0
        elif kind == "yaw":
            out.dyaw[:] = 0.0
        elif kind == "drop":
            out.fn[:] = False
        else:
            for name in EXTENDED_KINDS[kind]:
                array = getattr(out, name)
                if array is not None:
                    array[:] = NEUTRAL[name][0]
        return out

    def equals(self, other: "PerceptionErrors") -> bool:
        """The same arrays with the same values, to the bit (determinism's test)."""
        mine, theirs = self.arrays(), other.arrays()
        return mine.keys() == theirs.keys() and all(np.array_equal(mine[name], theirs[name]) for name in mine)


@lru_cache(maxsize=64)
def confidence_scores(num_frames: int, num_agents: int) -> np.ndarray:
    """Confidence of the detection of agent j at frame k: strictly distinct, in (0, 1).

    A fixed pseudo-random permutation of the object-frames, independent of the errors, so an attack
    can neither exploit ties (the devkit would take ATE and AOE from a single box) nor choose which
    of its errors the precision-recall curve sees first. A late, resized, flipped or wrongly fast
    detection keeps its cell's confidence: these are errors of a detection, not new detections.
    """
    count = num_frames * num_agents
    rank = np.random.default_rng(CONFIDENCE_SEED).permutation(count)
    scores = ((rank + 1.0) / (count + 1.0)).reshape(num_frames, num_agents)
    scores.setflags(write=False)
    return scores


@lru_cache(maxsize=64)
def ghost_scores(num_frames: int, num_agents: int, ghosts: int) -> np.ndarray:
    """Confidence of ghost slot g at frame k: every ghost inside one narrow band between two adjacent
    real confidences, the band above the share `GHOST_CONFIDENCE_QUANTILE` of the real ones.

    A ghost's cost in AP is its rank among the real detections (a false positive below every true
    one costs almost nothing). Were the score fixed per slot or per place, the search would learn to
    switch on only the low-scored ghosts, a stealth no detector has (its false positives are scored
    by the same network as its true ones). In one band every ghost outranks the same real detections
    whatever the attack does; the band's own order (a second fixed permutation) only decides between
    two ghosts that compete for one car, and is never chosen either. No score ties a real one.
    """
    real = num_frames * num_agents
    below = round(GHOST_CONFIDENCE_QUANTILE * real)  # real confidences (r + 1) / (real + 1) below the band: r < below
    count = num_frames * ghosts
    rank = np.random.default_rng(GHOST_CONFIDENCE_SEED).permutation(count)
    scores = ((below + (rank + 1.0) / (count + 1.0)) / (real + 1.0)).reshape(num_frames, ghosts)
    scores.setflags(write=False)
    return scores


def latency_source(valid: np.ndarray, latency: np.ndarray, rows: slice) -> np.ndarray:
    """The frame each detection of `rows` shows: `latency` frames back, but never before the agent's
    present appearance (an agent that was absent in between is shown as it was when it came back),
    so a late detection is always of a car that was there. Reads only frames up to the rows' own,
    which is what lets the injector node answer each frame as it arrives."""
    frames = np.arange(valid.shape[0])[rows][:, None]
    lag = latency[rows]
    source = np.repeat(frames, valid.shape[1], axis=1)
    agents = np.arange(valid.shape[1])
    going = valid[rows].copy()  # an absent car is not shown: its own frame, as for no latency
    for back in range(1, int(lag.max(initial=0)) + 1):
        earlier = frames - back
        going &= (back <= lag) & (earlier >= 0) & valid[np.maximum(earlier, 0), agents]
        source[going] = np.broadcast_to(earlier, source.shape)[going]
    return source


def _offset(x: np.ndarray, y: np.ndarray, yaw: np.ndarray, dx: np.ndarray, dy: np.ndarray,
            dyaw: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The error of a detected box: its pose offset, yaw wrapped."""
    return x + dx, y + dy, wrap_angle(yaw + dyaw)


def _perceive(truth: BoxSequence, errors: PerceptionErrors, rows: slice) -> BoxSequence:
    """I(y, e) on the frames `rows` of `truth`: agent slots first, then the ghost slots. The one
    definition both `inject` and `inject_frame` use; it reads truth only up to its rows' frames."""
    agents = np.arange(truth.shape[1])
    if errors.latency is None:
        source = {name: getattr(truth, name)[rows] for name in BOX_FIELDS[:-1]}
    else:
        frames = latency_source(truth.valid, errors.latency, rows)
        source = {name: getattr(truth, name)[frames, agents] for name in BOX_FIELDS[:-1]}
    dyaw = errors.dyaw[rows] if errors.flip is None else errors.dyaw[rows] + np.pi * errors.flip[rows]
    seen = dict(source)
    seen["x"], seen["y"], seen["yaw"] = _offset(source["x"], source["y"], source["yaw"], errors.dx[rows],
                                                errors.dy[rows], dyaw)
    if errors.dvx is not None and errors.dvy is not None:
        seen["vx"], seen["vy"] = source["vx"] + errors.dvx[rows], source["vy"] + errors.dvy[rows]
    if errors.length_scale is not None and errors.width_scale is not None:
        seen["length"] = source["length"] * errors.length_scale[rows]
        seen["width"] = source["width"] * errors.width_scale[rows]
    seen["score"] = confidence_scores(*truth.shape)[rows]
    out = BoxSequence(ids=truth.ids[rows], valid=truth.valid[rows] & ~errors.fn[rows], **seen)
    return out if errors.ghost_on is None else _with_ghosts(out, errors, rows)


def _with_ghosts(perceived: BoxSequence, errors: PerceptionErrors, rows: slice) -> BoxSequence:
    """`perceived` with the ghost slots after the agents': ids -1, -2, ... (never an agent's)."""
    assert errors.ghost_on is not None and errors.ghost_x is not None and errors.ghost_y is not None
    assert errors.ghost_yaw is not None and errors.ghost_vx is not None and errors.ghost_vy is not None
    shape = errors.ghost_on[rows].shape
    ghosts = {
        "ids": np.broadcast_to(-1 - np.arange(shape[1], dtype=np.int64), shape), "valid": errors.ghost_on[rows],
        "x": errors.ghost_x[rows], "y": errors.ghost_y[rows], "yaw": wrap_angle(errors.ghost_yaw[rows]),
        "vx": errors.ghost_vx[rows], "vy": errors.ghost_vy[rows], "length": np.full(shape, GHOST_LENGTH),
        "width": np.full(shape, GHOST_WIDTH), "height": np.full(shape, GHOST_HEIGHT),
        "score": ghost_scores(errors.shape[0], errors.shape[1], shape[1])[rows],
    }
    return BoxSequence(**{f.name: np.hstack([getattr(perceived, f.name), ghosts[f.name]]) for f in fields(perceived)})


def inject(truth: BoxSequence, errors: PerceptionErrors) -> BoxSequence:
    """I(y, e) over whole sequences: agent slots as in `truth` (the dropped ones invalid), then one
    slot per ghost."""
    if errors.shape != truth.shape:
        raise ValueError(f"error tensor shape {errors.shape} does not match ground truth {truth.shape}")
    return _perceive(truth, errors, slice(None))


def inject_frame(history: BoxSequence, frame: int, errors: PerceptionErrors) -> dict[str, np.ndarray]:
    """I(y, e) for one frame, as the graph's injector node applies it: `history` the ground truth
    of the rollout's frames so far in the error tensor's slots (frames to come may be left invalid),
    `frame` the one to perceive. The boxes are `inject`'s for that frame, float for float and in the
    same order."""
    return _perceive(history, errors, slice(frame, frame + 1)).frame(0)
