"""Rollouts forked from a snapshot: a rollout starts where its perception first differs from an earlier one's.

A rollout is a pure function of the scenario, the stack and what the tracker is handed each frame (the
detections after the errors, latency and velocity handling included). So the state of the stack at the
start of frame k (tracker, planner, ego, rule measures, reactive agents) is a function of the detections
of frames 0..k-1 alone, and two rollouts whose detections agree up to frame k agree up to there. `Forks`
keeps snapshots of those states keyed by a digest of the detections that led to them; a rollout looks up
the deepest one on its own detections' path, restores it, and drives on from there: the same numbers, bit
for bit, as driving from frame 0 (test_forks checks every bundled planner and every error kind).

The snapshots of one process's rollouts sit in a least-recently-used cache bounded in bytes; within a
path the shallower snapshots are always the more recent, so the cache gives up leaves before the trunks
they grow from. A planner forks when it has `snapshot`/`restore` (planners.base.Snapshots); one without
is deep-copied once a forked rollout of it has been checked equal to a full one, else rolled out whole
(`PlannerSnapshots.of`; the backend logs which, once).
"""

import copy
import hashlib
import sys
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, fields, is_dataclass
from typing import Any, cast

import numpy as np

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.planners.base import Planner, Snapshots
from advperc_ros.core.scenario import EgoState

ROOT = b"advperc rollout"  # the key of the state at frame 0, before any detection
NATIVE, DEEP_COPY, WHOLE = "native", "deep copy", "whole"


def next_key(key: bytes, frame: dict[str, np.ndarray]) -> bytes:
    """The key of the state after the tracker is handed `frame`, from the key of the state before: a digest of
    every detection so far, each array's name, type, shape and bytes."""
    digest = hashlib.blake2b(key, digest_size=16)
    for name in sorted(frame):
        array = np.ascontiguousarray(frame[name])
        digest.update(f"{name}:{array.dtype.str}:{array.shape}".encode())
        digest.update(array.data)
    return digest.digest()


@dataclass(frozen=True)
class Trunk:
    """What a finished rollout leaves its snapshots, shared by all of them: its ego states, the distances it
    measured during the drive (where `measured`), which frames its planner's fallback answered, and its
    agents when traffic reacted (frames up to a snapshot's are those the snapshot's state had written)."""

    ego: np.ndarray  # (K, 4) frames 0..K-1
    distances: np.ndarray  # (K, N), read only where `measured`
    measured: np.ndarray  # (K,) bool
    fallback_frames: tuple[int, ...]
    agents: BoxSequence | None


@dataclass(frozen=True)
class FrameState:
    """The stack at the start of frame `frame`, before the frame is perceived: the ego there, the tracker's and
    planner's snapshots, the reactive agents' simulation, and how many planner failures and fallback frames
    the rollout had counted."""

    frame: int
    ego: EgoState
    tracker: object
    planner: object
    traffic: Any
    failures: int
    fallbacks: int


@dataclass(frozen=True)
class Fork:
    """Where a rollout starts: a snapshot and the rollout it belongs to."""

    state: FrameState
    trunk: Trunk


@dataclass
class _Held:
    """A trunk in the cache: how many of its snapshots are left there, and its bytes."""

    trunk: Trunk
    snapshots: int
    size: int


@dataclass(frozen=True)
class PlannerSnapshots:
    """How a planner's state is kept and put back: its own `snapshot`/`restore` (NATIVE), a deep copy of its
    attributes (DEEP_COPY: trusted once a forked rollout equals a full one), or not at all (WHOLE)."""

    how: str

    @classmethod
    def of(cls, planner: Planner) -> "PlannerSnapshots":
        """NATIVE for a planner with the Snapshots protocol; DEEP_COPY for one whose attributes deep-copy;
        WHOLE otherwise (no attributes, or attributes that refuse to be copied)."""
        if isinstance(planner, Snapshots):
            return cls(NATIVE)
        try:
            copy.deepcopy(vars(planner))
        except Exception:  # no __dict__ (slots, an extension type), or an attribute that cannot be copied
            return cls(WHOLE)
        return cls(DEEP_COPY)

    def take(self, planner: Planner) -> object:
        if self.how == NATIVE:
            return planner.snapshot()  # type: ignore[attr-defined]
        return copy.deepcopy(vars(planner))

    def put(self, planner: Planner, state: object) -> None:
        if self.how == NATIVE:
            planner.restore(state)  # type: ignore[attr-defined]
            return
        attributes = vars(planner)
        attributes.clear()
        attributes.update(copy.deepcopy(cast(dict, state)))  # the snapshot may be restored again


def footprint(value: object, seen: set[int] | None = None) -> int:
    """Bytes `value` holds, arrays and containers walked (each object counted once): what the cache counts."""
    seen = set() if seen is None else seen
    if id(value) in seen:
        return 0
    seen.add(id(value))
    if isinstance(value, np.ndarray):
        # an array that owns its data counts it in its own size; a view counts what it views once
        return sys.getsizeof(value) + (0 if value.base is None else footprint(value.base, seen))
    size = sys.getsizeof(value)
    if isinstance(value, dict):
        return size + sum(footprint(k, seen) + footprint(v, seen) for k, v in value.items())
    if isinstance(value, (tuple, list, set, frozenset)):
        return size + sum(footprint(item, seen) for item in value)
    if is_dataclass(value) and not isinstance(value, type):
        return size + sum(footprint(getattr(value, f.name), seen) for f in fields(value))
    if hasattr(value, "__dict__") and not isinstance(value, type):
        return size + footprint(vars(value), seen)
    return size


class Forks:
    """One process's snapshots of its rollouts' states, bounded by `memory` bytes; `planner` is how the
    attacked planner's state is kept. A rollout asks `find` where to start, `wants` which of its frames to
    snapshot, and hands its snapshots over with `keep` when it ends."""

    def __init__(self, memory: int, planner: PlannerSnapshots) -> None:
        self.memory = memory
        self.planner = planner
        self._states: OrderedDict[bytes, Fork] = OrderedDict()  # least recently used first
        self._sizes: dict[bytes, int] = {}  # bytes of each snapshot
        self._trunks: dict[int, _Held] = {}  # by id(trunk)
        self.used = 0  # bytes held
        self.peak = 0  # the most bytes held at once
        self.frames_skipped = 0  # frames rollouts did not drive again
        self.frames_driven = 0  # frames rollouts drove
        self.rollouts = self.forked = 0  # rollouts run with the cache, and those that started past frame 0
        self.last_fork: int | None = None  # the frame the latest rollout started at (None: from frame 0)
        self.disabled_because: str | None = None  # why rollouts are whole from now on, when `disable` said

    @property
    def enabled(self) -> bool:
        return self.memory > 0 and self.planner.how != WHOLE

    def disable(self, why: str) -> None:
        """Roll out whole from now on, `why` (a planner whose deep copies did not give a full rollout's
        numbers, or whose restore() failed)."""
        self.disabled_because = why
        self.planner = PlannerSnapshots(WHOLE)
        self._states.clear()
        self._sizes.clear()
        self._trunks.clear()
        self.used = 0

    def find(self, frame_of: Callable[[int, Fork | None], dict[str, np.ndarray]],
             frames: int) -> tuple[Fork | None, bytes]:
        """(the deepest snapshot on this rollout's path, its key): `frame_of(k, fork)` is what the tracker is
        handed at frame k, given the snapshot at frame k (whose trunk holds the agents of frames 0..k under
        reactive traffic). The path's snapshots become the most recently used, the shallower more so."""
        key, fork, path = ROOT, None, []
        for k in range(frames):
            found = self._states.get(key)
            if found is None:
                break
            fork = found
            path.append(key)
            if k + 1 == frames:
                break
            key = next_key(key, frame_of(k, fork))
        for seen in reversed(path):
            self._states.move_to_end(seen)
        if fork is None:
            return None, ROOT
        return fork, path[-1]

    def count(self, first: int, frames: int) -> None:
        """A rollout of `frames` frames that started at frame `first`."""
        self.rollouts += 1
        self.forked += first > 0
        self.frames_skipped += first
        self.frames_driven += frames - first

    def summary(self) -> str:
        """One line of what forking saved this process, for the log at the end of an attack."""
        total = self.frames_driven + self.frames_skipped
        return (f"{self.forked} of {self.rollouts} rollouts forked from a snapshot; {self.frames_driven} of {total} "
                f"frames driven ({self.frames_driven / max(total, 1):.0%}); snapshots held at most "
                f"{self.peak / 2**20:.1f} of {self.memory / 2**20:.0f} MB")

    def wants(self, key: bytes) -> bool:
        """Whether the state of that key is worth a snapshot (it is not kept yet)."""
        return key not in self._states

    def keep(self, snapshots: list[tuple[bytes, FrameState]], trunk: Trunk) -> None:
        """A finished rollout's snapshots (`snapshots`: in frame order), each keyed by the detections before it,
        the deepest first into the cache (so the first out); then the least recently used go until the cache fits
        in its memory. What several snapshots share (a plan held over frames, the solve times) counts once, with
        the shallowest of them: the last of them to leave the cache, as a path's shallower snapshots are always
        the more recently used."""
        if not snapshots:
            return
        seen: set[int] = set()
        held = self._trunks[id(trunk)] = _Held(trunk, len(snapshots), footprint(trunk, seen))
        sizes = [footprint(state, seen) for _, state in snapshots]
        self.used += held.size + sum(sizes)
        for (key, state), size in zip(reversed(snapshots), reversed(sizes)):
            self._states[key] = Fork(state, trunk)
            self._sizes[key] = size
        self.peak = max(self.peak, self.used)
        while self.used > self.memory and self._states:
            key, fork = self._states.popitem(last=False)
            self.used -= self._sizes.pop(key)
            held = self._trunks[id(fork.trunk)]
            held.snapshots -= 1
            if held.snapshots == 0:
                self.used -= held.size
                del self._trunks[id(fork.trunk)]
