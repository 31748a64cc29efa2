"""The error tensor e and the error space the search draws it from.

Each array belongs to one kind (`registry.KINDS`); the tensor's operations loop over the kinds, so
none of them names one.
"""

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import advperc_ros.core.perception_errors.registry as registry
from advperc_ros.core.perception_errors.kind import ArraySpec, ErrorKind
from advperc_ros.core.perception_errors.registry import PAPER_ARRAYS, PAPER_KINDS

_EXTENDED: list[Any] = [None, frozenset()]  # [the registry's KINDS when last read, their extended arrays' names]


def _extended_names() -> frozenset[str]:
    """The names of the registered kinds' arrays beyond the paper's, kept while `registry.KINDS` is the
    same tuple (a test may register a kind of its own)."""
    if _EXTENDED[0] is not registry.KINDS:
        _EXTENDED[:] = [registry.KINDS, frozenset(registry.array_specs()) - frozenset(PAPER_ARRAYS)]
    names: frozenset[str] = _EXTENDED[1]
    return names


@dataclass(frozen=True, init=False)
class ErrorSpace:
    """Which errors the search may make and how large: the kinds on (`ERROR_KINDS` order) and the limits
    the extended ones declare (`ErrorKind.bounds`), read as attributes (`space.max_scale`) and given as
    keywords (`ErrorSpace(kinds, max_scale=1.6)`), each its kind's default unless given. The paper's
    kinds are bounded by the search's own moves (a push stays within a match threshold, a drop is a
    drop)."""

    kinds: tuple[str, ...]
    bounds: tuple[tuple[str, float | int], ...]  # (name, value) of every registered bound, in kind order

    def __init__(self, kinds: tuple[str, ...] = PAPER_KINDS, **bounds: float | int) -> None:
        declared = registry.bounds()
        unknown = sorted(set(bounds) - set(declared))
        if unknown:
            raise TypeError(f"ErrorSpace got '{unknown[0]}', which no error kind declares as a bound")
        object.__setattr__(self, "kinds", tuple(kinds))
        object.__setattr__(self, "bounds", tuple((name, bounds.get(name, bound.default))
                                                 for name, bound in declared.items()))

    def __getattr__(self, name: str) -> Any:
        """A kind's bound by name; any other name is no attribute (pickling looks up optional methods)."""
        for bound, value in self.__dict__.get("bounds", ()):
            if bound == name:
                return value
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def blank(self, num_frames: int, num_agents: int) -> "PerceptionErrors":
        """No error, with an array for every kind on."""
        return PerceptionErrors.none(num_frames, num_agents, self.kinds, self.ghosts)


@dataclass(frozen=True)
class PerceptionErrors:
    """The error tensor e: per frame and agent a position and yaw offset and a dropped flag (the
    paper's), and the arrays of whatever extended kinds are on. Everything the search changes is in it
    and nothing else, so an attack is this tensor; it is saved with the results (attack_errors.npz) and
    replayed from there. The paper's arrays are its fields; an extended kind's are in `extended`, read
    as attributes by their registered names (`errors.dvx`; None while the kind is off), so a kind adds
    its module and its registry line and nothing here. `arrays()` keeps the registry's order."""

    dx: np.ndarray  # (T, N) metres
    dy: np.ndarray  # (T, N) metres
    dyaw: np.ndarray  # (T, N) rad
    fn: np.ndarray  # (T, N) bool, True drops the detection
    extended: Mapping[str, np.ndarray] = field(default_factory=dict)  # the extended kinds' arrays on, by name

    def __getattr__(self, name: str) -> np.ndarray | None:
        """An extended kind's array (None while its kind is off); a name no kind registers is no attribute
        (so pickling and copying, which look up optional methods by name, find nothing here)."""
        if name not in _extended_names():
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        return self.__dict__.get("extended", {}).get(name)

    @classmethod
    def of(cls, **arrays: np.ndarray) -> "PerceptionErrors":
        """The tensor of these named arrays, unchecked (`from_arrays` checks a file's or a message's)."""
        dx, dy, dyaw, fn = (arrays[name] for name in PAPER_ARRAYS)
        return cls(dx, dy, dyaw, fn, extended={name: array for name, array in arrays.items() if name not in PAPER_ARRAYS})

    def with_arrays(self, **arrays: np.ndarray | None) -> "PerceptionErrors":
        """The same tensor with these arrays in place (the arrays themselves, not copies); an extended
        array given as None is taken out."""
        unknown = sorted(set(arrays) - _extended_names() - set(PAPER_ARRAYS))
        if unknown:
            raise ValueError(f"field '{unknown[0]}' is no part of an error tensor")
        merged = {**self.arrays(), **arrays}
        return type(self).of(**{name: array for name, array in merged.items() if array is not None})

    @classmethod
    def none(cls, num_frames: int, num_agents: int, kinds: tuple[str, ...] = PAPER_KINDS,
             ghosts: int = 0) -> "PerceptionErrors":
        """No error at all, with the arrays of the extended `kinds` (`ghosts` slots per frame)."""
        shape = (num_frames, num_agents)
        out = cls.of(**{spec.name: np.full(shape, spec.neutral, dtype=spec.dtype)
                        for kind in registry.KINDS if kind.paper for spec in kind.arrays})
        for kind in kinds:
            out = out.with_kind(kind, ghosts)
        return out

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> "PerceptionErrors":
        """The tensor these named arrays make (a file's, a message's), checked: the paper's arrays and
        whole kinds only, one frames x agents shape (ghosts: frames x slots), each kind's element types
        (booleans where flags are, whole numbers, finite numbers) and floors (latencies of at least 0
        frames, scales above 0). A ValueError names the first field that is wrong."""
        specs = registry.array_specs()
        unknown = sorted(set(arrays) - set(specs))
        if unknown:
            raise ValueError(f"field '{unknown[0]}' is no part of an error tensor")
        paper = [kind.name for kind in registry.KINDS if kind.paper]
        groups = [(f"{', '.join(paper[:-1])} and {paper[-1]}", registry.PAPER_ARRAYS, True)]
        groups += [(kind.name, kind.array_names, False) for kind in registry.KINDS if not kind.paper]
        for label, names, required in groups:
            present = [name for name in names if name in arrays]
            if (present and len(present) < len(names)) or (required and not present):
                missing = next(name for name in names if name not in arrays)
                raise ValueError(f"field '{missing}' is missing ({label} needs {', '.join(names)})")
        shape = np.shape(arrays["fn"])  # the tensor's shape, as `shape` says
        ghost_shape = next((np.shape(arrays[name]) for name, spec in specs.items() if spec.per_ghost and name in arrays),
                           None)
        checked: dict[str, np.ndarray] = {}
        for name, raw in arrays.items():
            array, spec = np.asarray(raw), specs[name]
            wanted = ghost_shape if spec.per_ghost else shape
            if array.ndim != 2 or array.shape != wanted or (ghost_shape is not None and ghost_shape[0] != shape[0]):
                slots = "ghost slots" if spec.per_ghost else "agents"
                raise ValueError(f"field '{name}' must be a frames x {slots} array of the tensor's {shape[0]} frames")
            dtype = spec.dtype
            if (dtype is np.bool_ and array.dtype.kind != "b") or (dtype is np.int64 and array.dtype.kind not in "iu"):
                raise ValueError(f"field '{name}' must hold {'booleans' if dtype is np.bool_ else 'whole numbers'}")
            if dtype is np.float64 and (array.dtype.kind not in "fiu" or not np.isfinite(array).all()):
                raise ValueError(f"field '{name}' must hold finite numbers")
            if not spec.admits(array):
                raise ValueError(f"field '{name}' must be {spec.floor()} everywhere")
            checked[name] = array.astype(dtype)
        return cls.of(**checked)

    @property
    def shape(self) -> tuple[int, int]:
        return self.fn.shape

    @property
    def ghost_slots(self) -> int:
        """Ghost slots per frame: the width of the per-ghost arrays, 0 without them."""
        widths = (array.shape[1] for name, spec in registry.array_specs().items()
                  if spec.per_ghost and (array := getattr(self, name)) is not None)
        return next(widths, 0)

    @property
    def kinds(self) -> tuple[str, ...]:
        """The paper's kinds and the extended ones this tensor has arrays for."""
        return tuple(kind.name for kind in registry.KINDS if kind.present(self))

    def arrays(self) -> dict[str, np.ndarray]:
        """Every array it has, by name, in the registry's order (what files, messages and digests hold)."""
        return {name: array for name in registry.array_specs() if (array := getattr(self, name)) is not None}

    def with_kind(self, kind: str, ghosts: int = 0) -> "PerceptionErrors":
        """These errors with the arrays of `kind`, neutral where they were absent (itself if present)."""
        record = registry.kind_named(kind)
        if record.present(self):
            return self
        return self.with_arrays(**{spec.name: np.full((self.shape[0], ghosts) if spec.per_ghost else self.shape,
                                                      spec.neutral, dtype=spec.dtype) for spec in record.arrays})

    def copy(self) -> "PerceptionErrors":
        return type(self).of(**{name: array.copy() for name, array in self.arrays().items()})

    def with_drop(self, agent: int, start: int, end: int) -> "PerceptionErrors":
        """These errors plus agent `agent` dropped on frames start..end inclusive."""
        out = self.copy()
        out.fn[start : end + 1, agent] = True
        return out

    def _agent_arrays(self, attacking: bool = False) -> Iterator[tuple[ArraySpec, np.ndarray]]:
        """(spec, array) of every per-agent array it has (`attacking`: of the kinds that attack alone)."""
        for kind in registry.KINDS:
            for spec in kind.arrays if kind.attacks or not attacking else ():
                array = getattr(self, spec.name)
                if array is not None and not spec.per_ghost:
                    yield spec, array

    def perceive_perfectly(self, first: int, last: int, slot: int) -> None:
        """In place: agent `slot` detected without any error on frames first..last inclusive."""
        for spec, array in self._agent_arrays():
            array[first : last + 1, slot] = spec.neutral

    def attacked(self) -> np.ndarray:
        """(frames x agents) the object-frames shown other than they are: dropped, displaced, turned,
        lagging, resized or wrongly fast (a yaw error alone is noise, as the paper's proposals add it)."""
        out = np.zeros(self.shape, dtype=bool)
        for spec, array in self._agent_arrays(attacking=True):
            out |= array != spec.neutral
        return out

    def used_kinds(self, frames: int) -> tuple[str, ...]:
        """The kinds whose errors show in the first `frames` frames (a dropped detection shows no other)."""
        rows = slice(0, frames)
        shown = ~self.fn[rows]

        def used(kind: ErrorKind) -> bool:
            if kind.used is not None:
                return kind.used(self, rows)
            return kind.present(self) and any(bool((getattr(self, spec.name)[rows] != spec.neutral)[shown].any())
                                              for spec in kind.arrays)

        return tuple(kind.name for kind in registry.KINDS if used(kind))

    def without(self, kind: str) -> "PerceptionErrors":
        """A copy with no error of `kind` (a dropped detection shown again, without an offset)."""
        out = self.copy()
        for spec in registry.kind_named(kind).arrays:
            array = getattr(out, spec.name)
            if array is not None:
                array[:] = spec.neutral
        return out

    def equals(self, other: "PerceptionErrors") -> bool:
        """The same arrays with the same values, to the bit (determinism's test)."""
        mine, theirs = self.arrays(), other.arrays()
        return mine.keys() == theirs.keys() and all(np.array_equal(mine[name], theirs[name]) for name in mine)
