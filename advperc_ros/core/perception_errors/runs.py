"""Runs of consecutive object-frames in a (frames x slots) mask: the spans a search acts on.

Here, below the kinds and the search, because both the kinds' moves and the search's phases pick
runs of attacked or dropped frames, and a kind's module may not import the search.
"""

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from advperc_ros.core.perception_errors.tensor import PerceptionErrors


def dropped_runs(fn: np.ndarray) -> list[tuple[int, int, int]]:
    """(slot, first, last) of every run of consecutive dropped frames, by slot then time."""
    runs = []
    for j in np.flatnonzero(fn.any(axis=0)):
        edges = np.diff(np.concatenate([[0], fn[:, j].astype(np.int8), [0]]))
        runs += [(int(j), int(a), int(b) - 1) for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1))]
    return runs


def run_edge(first: int, last: int, rng: np.random.Generator) -> tuple[int, int]:
    """(a, b): the first or last k frames of the run first..last, k uniform up to half the run: the
    frames a move towards no error takes back."""
    k = int(rng.integers(1, max(1, (last - first + 1) // 2) + 1))
    return (first, first + k - 1) if rng.integers(2) else (last - k + 1, last)


def attacked_runs(errors: "PerceptionErrors", frames: int) -> list[tuple[int, int, int]]:
    """(slot, first, last) of every run of attacked object-frames (`PerceptionErrors.attacked`)."""
    return dropped_runs(errors.attacked()[:frames])
