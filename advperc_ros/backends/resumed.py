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
goes on (floats as `repr`, exact). A line cut short by a kill is ignored: that rollout runs again.
An attack killed before its first checkpoint resumes from the start. The folder goes when the
results folder is complete; a fresh attack refuses to start over a checkpoint it would lose.
"""

import hashlib
import json
import math
import os
import shutil
from pathlib import Path

import numpy as np

from advperc_ros.backends.base import AttackedPlanner, Rollouts
from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.rollout import RolloutConfig, RolloutResult, judge
from advperc_ros.params import AttackParams, ParamsError

PARAMS = "params.json"
ROLLOUTS = "rollouts.jsonl"


def checkpoint_folder(output: Path) -> Path:
    return output.parent / f".{output.name}.checkpoint"


def _digest(errors: PerceptionErrors) -> str:
    sha = hashlib.sha256()
    for array in (errors.dx, errors.dy, errors.dyaw, errors.fn):
        sha.update(np.ascontiguousarray(array).tobytes())
    return sha.hexdigest()


def _record(errors: PerceptionErrors, result: RolloutResult) -> str:
    return json.dumps({"errors": _digest(errors), "ego": result.ego.tolist(),
                       "distances": [[None if math.isinf(d) else d for d in row] for row in result.distances.tolist()],
                       "inconclusive": result.inconclusive, "planner_failures": result.planner_failures})


def _result(record: dict) -> RolloutResult:
    distances = np.array([[np.inf if d is None else d for d in row] for row in record["distances"]], dtype=float)
    ego = np.array(record["ego"], dtype=float).reshape(-1, 4)
    return RolloutResult(ego=ego, distances=distances.reshape(ego.shape[0], -1), inconclusive=record["inconclusive"],
                         planner_failures=record["planner_failures"])


class Checkpoint:
    """The rollouts of one attack so far, on disk next to its (future) results folder."""

    def __init__(self, output: Path, params: AttackParams, resume: bool) -> None:
        self.folder = checkpoint_folder(output)
        identity = json.dumps(params.canonical(), sort_keys=True)
        if resume and (self.folder / PARAMS).is_file():
            if (self.folder / PARAMS).read_text() != identity:
                raise ParamsError(f"{self.folder}: the checkpoint is of an attack with other params; "
                                  "resume with the params it began with")
            self.done = self._load()
        else:  # a fresh attack, or one killed before its first checkpoint
            if self.folder.exists() and not resume:
                raise ParamsError(f"{output}: an interrupted attack left {self.folder}: finish it with --resume "
                                  f"{output}, or delete that folder")
            shutil.rmtree(self.folder, ignore_errors=True)
            self.folder.mkdir(parents=True)
            (self.folder / PARAMS).write_text(identity)
            self.done = []
        self._file = (self.folder / ROLLOUTS).open("a")

    def _load(self) -> list[dict]:
        path = self.folder / ROLLOUTS
        if not path.exists():
            return []
        records = []
        with path.open() as handle:
            for line in handle:
                try:
                    records.append(json.loads(line))
                except json.JSONDecodeError:  # the line a kill cut short: its rollout runs again
                    break
        # rewrite without a torn tail, so appends start on a clean line
        path.write_text("".join(_record_line(r) for r in records))
        return records

    def append(self, errors: PerceptionErrors, result: RolloutResult) -> None:
        self._file.write(_record(errors, result) + "\n")
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self, finished: bool) -> None:
        """Keep the checkpoint for --resume, or remove it once the results folder is complete (or
        when the attack ended before its first rollout: nothing to resume, nothing left behind)."""
        self._file.close()
        if finished or not (self.folder / ROLLOUTS).stat().st_size:
            shutil.rmtree(self.folder, ignore_errors=True)


def _record_line(record: dict) -> str:
    return json.dumps(record) + "\n"


class ResumedRollouts:
    """A backend whose rollouts already in the checkpoint are answered from it, in order; the rest
    run on `backend` and are appended. Recorded rollouts (tracks, plans) always run."""

    def __init__(self, backend: Rollouts, checkpoint: Checkpoint, agents: BoxSequence, config: RolloutConfig) -> None:
        self._backend = backend
        self._checkpoint = checkpoint
        self._agents = agents
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
        backend (at once where it can), each appended as the batch completes."""
        stored: list[RolloutResult] = []
        while len(stored) < len(batch) and self._next < len(self._checkpoint.done):
            record, errors = self._checkpoint.done[self._next], batch[len(stored)]
            if record["errors"] != _digest(errors):
                raise ParamsError(f"{self._checkpoint.folder}: rollout {self._next + 1} differs from the one recorded: "
                                  "the checkpoint is of another attack (or another version of this tool)")
            stored.append(judge(_result(record), self._agents, self._config))
            self._next += 1
        rest = batch[len(stored):]
        many = getattr(self._backend, "rollout_many", None)
        fresh = many(rest) if many is not None and len(rest) > 1 else [self._backend.rollout(e) for e in rest]
        for errors, result in zip(rest, fresh):
            self._checkpoint.append(errors, result)
        self._next += len(rest)
        return stored + fresh
