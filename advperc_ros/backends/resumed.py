"""The resumed backend, for resumable attacks: every rollout's result is kept on disk as it
completes, so a killed search (Ctrl-C, SIGKILL, a crash) finishes later with exactly the report it
would have written.

The search is a deterministic function of its params, seed and rollout results, so a checkpoint
need not hold the search's state (RNG, counters, best, log): resuming runs the search again and
answers each rollout it already ran from the checkpoint, in order, instead of rolling it out.
What a rollout is asked for is checked against what was recorded (sha256 of the error tensor), so
a checkpoint can only finish the attack it began.

Layout: `<output parent>/.<output name>.checkpoint/` holds `params.json` (the canonical params and
seed) and `rollouts.jsonl`, one line per rollout appended and flushed to disk before the search
goes on (floats as `repr`, exact). A resume checks every line before it uses any, since a
checkpoint is outside input (disks fail, people edit files): a mapping of exactly the fields
below, `ego` 1 to T rows (the scenario's frames) of 4 finite numbers, `distances` one row per ego
row of a finite number or null (+inf) per agent of the scenario, `inconclusive` null or a string,
`planner_failures` null or a count. Each line's `chain` is the sha256 of the params, the previous
line's chain and the line's own content, so a value edited by hand, a line moved, or one taken from
another attack's checkpoint is refused as well (against accidents, not a forger: sha256 has no
key). Anything wrong refuses the checkpoint in one line naming the file and line, before the files
are touched; deleting the folder starts the attack over. A resume runs the first inconclusive rollout again
(a planner that had died, a node gone silent) and drops what followed it. Only the last line may be cut short (a
kill mid-write: no newline, not JSON): it is dropped and that rollout runs again. An attack killed
before its first checkpoint resumes from the start. The folder goes when the results folder is
complete; a fresh attack refuses to start over a checkpoint it would lose. The caller holds the
output's lock (`application.attack_to_folder`), so a running attack's checkpoint is its alone.
"""

import hashlib
import json
import math
import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from advperc_ros.backends.base import AttackedPlanner, Rollouts
from advperc_ros.core.perception_errors import PAPER_ARRAYS, PerceptionErrors
from advperc_ros.core.rollout import RolloutConfig, RolloutResult, judge
from advperc_ros.core.scenario import Scenario
from advperc_ros.core.staging import staging_path
from advperc_ros.exceptions import OutputError, ResultsError

PARAMS = "params.json"
ROLLOUTS = "rollouts.jsonl"
FIELDS = ("errors", "ego", "distances", "inconclusive", "planner_failures", "chain")  # a line's, as written
SHA256 = re.compile(r"[0-9a-f]{64}")


def checkpoint_folder(output: Path) -> Path:
    return output.parent / f".{output.name}.checkpoint"


@dataclass(frozen=True)
class Stored:
    """A checkpointed rollout: the digest of the errors it was asked for, and what it gave."""

    errors: str
    result: RolloutResult


def _digest(errors: PerceptionErrors) -> str:
    sha = hashlib.sha256()
    for name, array in errors.arrays().items():  # the paper's four alone as ever: their digests stay valid
        if name not in PAPER_ARRAYS:
            sha.update(name.encode())
        sha.update(np.ascontiguousarray(array).tobytes())
    return sha.hexdigest()


def _chain(identity: str, previous: str, content: str) -> str:
    """A line's `chain`: its content bound to the attack (the params) and to the line before it
    ('' for the first), so an edit, a move or a line of another checkpoint breaks it."""
    return hashlib.sha256("\n".join((identity, previous, content)).encode()).hexdigest()


def _content(errors: PerceptionErrors, result: RolloutResult) -> dict:
    """A line's fields but its chain."""
    return {"errors": _digest(errors), "ego": result.ego.tolist(),
            "distances": [[None if math.isinf(d) else d for d in row] for row in result.distances.tolist()],
            "inconclusive": result.inconclusive, "planner_failures": result.planner_failures}


def _parsed(raw: bytes) -> object:
    """A line's JSON value, else a ValueError (bytes not UTF-8 are one too)."""
    try:
        return json.loads(raw.decode())
    except RecursionError:  # `[[[[...`: the parser's own stack
        raise ValueError("nested too deep") from None


def _fields(line: object) -> dict:
    """A line's JSON value as the mapping of its fields, else a ValueError."""
    if not isinstance(line, dict) or set(line) != set(FIELDS):
        raise ValueError(f"not a checkpointed rollout (a mapping of exactly {', '.join(FIELDS)})")
    return line


def _stored(line: dict, shape: tuple[int, int]) -> Stored:
    """A line's rollout, checked against the scenario's (frames, agents) `shape`; else a ValueError
    saying what is wrong with it."""
    for name in ("errors", "chain"):
        if not isinstance(line[name], str) or not SHA256.fullmatch(line[name]):
            raise ValueError(f"'{name}' is not a sha256 digest (64 lowercase hex digits)")
    if line["inconclusive"] is not None and not isinstance(line["inconclusive"], str):
        raise ValueError("'inconclusive' is neither null nor a string")
    failures = line["planner_failures"]
    if failures is not None and (type(failures) is not int or failures < 0):
        raise ValueError("'planner_failures' is neither null nor a count (an integer, at least 0)")
    frames, agents = shape
    ego = _table(line["ego"], "ego", range(1, frames + 1), 4, nullable=False)
    distances = _table(line["distances"], "distances", range(len(ego), len(ego) + 1), agents, nullable=True)
    return Stored(line["errors"], RolloutResult(ego=ego, distances=distances, inconclusive=line["inconclusive"],
                                                planner_failures=failures))


def _table(value: object, name: str, rows: range, width: int, nullable: bool) -> np.ndarray:
    """`value` as a float array of `rows` rows of `width` finite numbers (or, when `nullable`, null:
    +inf); else a ValueError naming the row and column."""
    if not isinstance(value, list) or len(value) not in rows:
        count = rows.start if len(rows) == 1 else f"{rows.start} to {rows.stop - 1}"
        raise ValueError(f"'{name}' is not a list of {count} rows")
    kind = "a finite number or null" if nullable else "a finite number"
    for k, row in enumerate(value):
        if not isinstance(row, list) or len(row) != width:
            raise ValueError(f"'{name}' row {k} is not a list of {width} values")
        for j, cell in enumerate(row):
            if not ((type(cell) is float and math.isfinite(cell)) or (nullable and cell is None)):
                raise ValueError(f"'{name}' row {k} column {j} is not {kind}")
    return np.array([[np.inf if cell is None else cell for cell in row] for row in value], dtype=float)


class Checkpoint:
    """The rollouts of one attack so far, on disk next to its (future) results folder; `canonical` is
    the attack's `CoreConfigs.canonical`, what its results are a function of."""

    def __init__(self, output: Path, canonical: str, scenario: Scenario, resume: bool) -> None:
        self.folder = checkpoint_folder(output)
        self._identity = canonical
        if os.path.lexists(self.folder) and (self.folder.is_symlink() or not self.folder.is_dir()):
            raise self._damaged(self.folder, "not a folder")
        rollouts = self.folder / ROLLOUTS
        if resume and os.path.lexists(rollouts):
            if self._read(self.folder / PARAMS) != self._identity.encode():
                raise ResultsError(f"{self.folder / PARAMS}: the checkpoint is of an attack with other params (or "
                                   "damaged): resume with the params it began with, or delete "
                                   f"{self.folder} to start the attack over")
            self.done, self._last = self._load(rollouts, scenario.agents.shape)
        else:  # a fresh attack, or one killed before its first checkpoint
            if os.path.lexists(self.folder) and not resume:
                raise OutputError(f"{output}: an interrupted attack left {self.folder}: finish it with --resume "
                                  f"{output}, or delete that folder")
            shutil.rmtree(self.folder, ignore_errors=True)
            self.folder.mkdir(parents=True)
            (self.folder / PARAMS).write_text(self._identity)
            self.done, self._last = [], ""
        self._file = rollouts.open("a")

    def _damaged(self, path: Path, what: str) -> ResultsError:
        """The one line refusing a damaged checkpoint: the file, what is wrong, and the way on."""
        return ResultsError(f"{path}: {what}; the checkpoint cannot be resumed: delete {self.folder} to start the "
                            "attack over")

    def _read(self, path: Path) -> bytes:
        """A checkpoint file's bytes; a folder, a FIFO (it would block) or an unreadable file is damage."""
        if not path.is_file():
            raise self._damaged(path, "missing or not a regular file")
        try:
            return path.read_bytes()
        except OSError as exc:
            raise self._damaged(path, f"cannot be read ({exc.strerror})") from None

    def _load(self, path: Path, shape: tuple[int, int]) -> tuple[list[Stored], str]:
        """The checkpointed rollouts and the last one's chain, every line checked before the file is
        touched; then the file keeps its whole lines alone (a last line cut short is dropped), up to the
        first inconclusive rollout: a resume rolls that one out again, never reports on it."""
        data = self._read(path)
        *lines, tail = data.split(b"\n")  # tail: b"" when the last line is whole
        done: list[Stored] = []
        kept: list[bytes] = []
        last = ""
        for n, raw in enumerate([*lines, tail] if tail else lines, 1):
            try:
                line = _parsed(raw)
            except ValueError:
                if n > len(lines):  # the tail, no newline and not JSON: a kill cut it short, its rollout runs again
                    break
                raise self._damaged(path, f"line {n} is not JSON (only the last line may be cut short, by a kill)") from None
            try:
                fields = _fields(line)
                stored = _stored(fields, shape)
            except ValueError as exc:
                raise self._damaged(path, f"line {n}: {exc}") from None
            chain = self._follow(path, n, fields, last)
            if stored.result.inconclusive is not None:  # a planner or node that failed then: run it again, and what
                break  # followed it, which the search decided on an inconclusive rollout, is not this search's
            done.append(stored)
            last = chain
            kept.append(raw)
        whole = b"".join(raw + b"\n" for raw in kept)
        if whole != data:
            _replace(path, whole)
        return done, last

    def _follow(self, path: Path, n: int, line: dict, previous: str) -> str:
        """Line `n`'s chain, checked to follow `previous` with this line's content."""
        content = {name: value for name, value in line.items() if name != "chain"}
        if _chain(self._identity, previous, json.dumps(content)) != line["chain"]:
            raise self._damaged(path, f"line {n} was changed after it was written, moved, or comes from another "
                                      "attack's checkpoint (its 'chain' does not follow)")
        return line["chain"]

    def append(self, errors: PerceptionErrors, result: RolloutResult) -> None:
        content = _content(errors, result)
        self._last = _chain(self._identity, self._last, json.dumps(content))
        self._file.write(json.dumps({**content, "chain": self._last}) + "\n")
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self, finished: bool) -> None:
        """Keep the checkpoint for --resume, or remove it once the results folder is complete (or
        when the attack ended before its first rollout: nothing to resume, nothing left behind)."""
        self._file.close()
        if finished or not (self.folder / ROLLOUTS).stat().st_size:
            shutil.rmtree(self.folder, ignore_errors=True)


def _replace(path: Path, data: bytes) -> None:
    """`path` holding `data`, whole or not at all: a kill mid-write leaves the old file."""
    staging = staging_path(path)
    with staging.open("wb") as handle:
        handle.write(data)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(staging, path)


class ResumedRollouts:
    """A backend whose rollouts already in the checkpoint are answered from it, in order; the rest
    run on `backend` and are appended. Recorded rollouts (tracks, plans) always run."""

    def __init__(self, backend: Rollouts, checkpoint: Checkpoint, scenario: Scenario, config: RolloutConfig) -> None:
        self._backend = backend
        self._checkpoint = checkpoint
        self._scenario = scenario
        self._config = config  # a stored rollout is judged again (at-fault), as every backend judges its own
        self._next = 0

    @property
    def attacked_planner(self) -> AttackedPlanner:
        return self._backend.attacked_planner

    def rollout(self, errors: PerceptionErrors, record: bool = False) -> RolloutResult:
        if record:
            return self._backend.rollout(errors, record=True)
        return self.rollout_many([errors])[0]

    def rollout_many(self, batch: list[PerceptionErrors]) -> list[RolloutResult]:
        """A batch's rollouts in order: those checkpointed from the checkpoint, the rest on the
        backend: at once where it can, appended as the batch completes; else one by one, each appended
        as it completes (a graph whose node died mid-batch keeps the batch's rollouts done before)."""
        stored: list[RolloutResult] = []
        observe = getattr(self._backend, "observe", None)
        while len(stored) < len(batch) and self._next < len(self._checkpoint.done):
            record, errors = self._checkpoint.done[self._next], batch[len(stored)]
            if record.errors != _digest(errors):
                raise ResultsError(f"{self._checkpoint.folder}: rollout {self._next + 1} differs from the one recorded: "
                                   "the checkpoint is of another attack (or another version of this tool)")
            stored.append(judge(record.result, self._scenario, self._config))
            if observe is not None:  # the graph publishes the ground truth's rollout for its rule monitor
                observe(errors, stored[-1])
            self._next += 1
        rest = batch[len(stored):]
        many = getattr(self._backend, "rollout_many", None)
        if many is not None and len(rest) > 1:
            fresh = many(rest)
            for errors, result in zip(rest, fresh):
                self._checkpoint.append(errors, result)
        else:
            fresh = []
            for errors in rest:
                fresh.append(self._backend.rollout(errors))
                self._checkpoint.append(errors, fresh[-1])
        self._next += len(rest)
        return stored + fresh
