"""A resumable attack's checkpoint is outside input: a damaged, hand-edited, reordered or mixed line is
refused in one line naming the file and the line (exit 2), and the checkpoint is left as it was; only a
last line cut short by a kill is dropped, and the attack still ends with the uninterrupted report. A
running attack's output is locked: a second attack on it ends in one line and touches nothing."""

import fcntl
import json
import os
import shutil
import signal
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO
from test_cli import write_params
from test_resume import _attack, _report

from advperc_ros import application
from advperc_ros.application import output_lock
from advperc_ros.backends.resumed import ROLLOUTS, Checkpoint, checkpoint_folder
from advperc_ros.cli import main
from advperc_ros.results.destination import exclusive

SHORT = {"search.heuristic.iterations": 1, "search.random.steps": 2}  # a real search of 18 rollouts
FRAMES, AGENTS = 251, 5  # idm_lane_following's


@dataclass(frozen=True)
class Kept:
    """A finished short attack's checkpoint, kept, with the report the attack wrote."""

    params: Path
    checkpoint: Path  # a pristine copy: each test resumes a copy of its own
    report: dict

    @property
    def lines(self) -> list[bytes]:
        return (self.checkpoint / ROLLOUTS).read_bytes().splitlines()


def kept_checkpoint(folder: Path) -> Kept:
    """Run a short attack to its end with its checkpoint kept (closed as an interrupted attack closes it)."""
    params = write_params(folder / "p.yaml", REPO, **SHORT)
    close = Checkpoint.close
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(Checkpoint, "close", lambda self, finished: close(self, False))
        assert main(["attack", str(params), "--output", str(folder / "whole"), "--quiet"]) == 0
    assert not output_lock(folder / "whole").exists()  # a finished attack leaves no lock behind
    shutil.move(checkpoint_folder(folder / "whole"), folder / "kept")
    return Kept(params, folder / "kept", _report(folder / "whole"))


def resume_with(kept: Kept, folder: Path, data: bytes) -> Path:
    """The output whose checkpoint is the kept one with `data` for its rollouts; --resume it to finish."""
    output = folder / "out"
    shutil.copytree(kept.checkpoint, checkpoint_folder(output))
    (checkpoint_folder(output) / ROLLOUTS).write_bytes(data)
    return output


def refused(argv: list[str], capsys, *says: str) -> None:
    """`advperc` ends in one line holding each of `says`, exit code 2."""
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("advperc: error:") and "Traceback" not in err, err
    for text in says:
        assert text in err, (text, err)


def resume_refused(kept: Kept, folder: Path, data: bytes, capsys, *says: str) -> None:
    """--resume of a checkpoint holding `data` is refused naming its rollouts file, and leaves it as it was."""
    output = resume_with(kept, folder, data)
    refused(["attack", str(kept.params), "--resume", str(output), "--quiet"], capsys,
            f"{checkpoint_folder(output) / ROLLOUTS}: ", f"delete {checkpoint_folder(output)}", *says)
    assert (checkpoint_folder(output) / ROLLOUTS).read_bytes() == data
    assert sorted(p.name for p in folder.iterdir()) == [checkpoint_folder(output).name]  # no lock, no output


@pytest.fixture(scope="module")
def kept(tmp_path_factory) -> Kept:
    return kept_checkpoint(tmp_path_factory.mktemp("kept"))


def joined(lines: list[bytes]) -> bytes:
    return b"".join(line + b"\n" for line in lines)


def edit(change: Callable[[dict], object]) -> Callable[[bytes], bytes]:
    """A line damage made on its mapping: `change` edits it in place (what it returns is left unused)."""
    def damage(raw: bytes) -> bytes:
        line = json.loads(raw)
        change(line)
        return json.dumps(line).encode()
    return damage


def put(field: str, *at_and_value) -> Callable[[dict], None]:
    """Set `line[field][i][j]...` (the last of `at_and_value` is the value)."""
    *at, value = at_and_value

    def change(line: dict) -> None:
        node, key = line, field
        for index in at:
            node, key = node[key], index
        node[key] = value
    return change


DAMAGED = [
    ("an empty mapping", lambda raw: b"{}", "not a checkpointed rollout"),
    ("a list", lambda raw: b"[1, 2]", "not a checkpointed rollout"),
    ("null", lambda raw: b"null", "not a checkpointed rollout"),
    ("a string", lambda raw: b'"errors"', "not a checkpointed rollout"),
    ("not UTF-8", lambda raw: raw[:40] + b"\xff\xfe" + raw[42:], "is not JSON"),
    ("cut short", lambda raw: raw[: len(raw) // 2], "is not JSON"),
    ("empty", lambda raw: b"", "is not JSON"),
    ("nested too deep for the parser", lambda raw: b"[" * 100_000, "is not JSON"),
    ("a field missing", edit(lambda line: line.pop("distances")), "not a checkpointed rollout"),
    ("a field more", edit(put("extra", 1)), "not a checkpointed rollout"),
    ("`errors` not a digest", edit(put("errors", "abc")), "'errors' is not a sha256 digest"),
    ("`chain` a number", edit(put("chain", 3)), "'chain' is not a sha256 digest"),
    ("`ego` a number", edit(put("ego", 3.0)), f"'ego' is not a list of 1 to {FRAMES} rows"),
    ("`ego` empty", edit(put("ego", [])), f"'ego' is not a list of 1 to {FRAMES} rows"),
    ("`ego` longer than the scenario", edit(lambda line: line["ego"].extend([line["ego"][0]] * FRAMES)),
     f"'ego' is not a list of 1 to {FRAMES} rows"),
    ("an `ego` row of 3 numbers", edit(lambda line: line["ego"][5].pop()), "'ego' row 5 is not a list of 4 values"),
    ("an `ego` row a mapping", edit(put("ego", 5, {})), "'ego' row 5 is not a list of 4 values"),
    ("an `ego` value a string", edit(put("ego", 5, 0, "1.0")), "'ego' row 5 column 0 is not a finite number"),
    ("an `ego` value true", edit(put("ego", 5, 0, True)), "'ego' row 5 column 0 is not a finite number"),
    ("an `ego` value an integer", edit(put("ego", 5, 0, 1)), "'ego' row 5 column 0 is not a finite number"),
    ("an `ego` value null", edit(put("ego", 5, 1, None)), "'ego' row 5 column 1 is not a finite number"),
    ("an `ego` value NaN", edit(put("ego", 5, 2, float("nan"))), "'ego' row 5 column 2 is not a finite number"),
    ("an `ego` value 1e999", lambda raw: raw.replace(b"[0.0, -1.75, 0.0, 8.0]", b"[1e999, -1.75, 0.0, 8.0]", 1),
     "'ego' row 0 column 0 is not a finite number"),
    ("`distances` a row short", edit(lambda line: line["distances"].pop()), "'distances' is not a list of"),
    ("a `distances` row an agent short", edit(lambda line: line["distances"][3].pop()),
     f"'distances' row 3 is not a list of {AGENTS} values"),
    ("a distance a string", edit(put("distances", 3, 0, "x")), "'distances' row 3 column 0 is not a finite number or null"),
    ("a distance -Infinity", edit(put("distances", 3, 1, -float("inf"))),
     "'distances' row 3 column 1 is not a finite number or null"),
    ("`inconclusive` a number", edit(put("inconclusive", 3)), "'inconclusive' is neither null nor a string"),
    ("`planner_failures` negative", edit(put("planner_failures", -1)), "'planner_failures' is neither null nor a count"),
    ("`planner_failures` a float", edit(put("planner_failures", 1.5)), "'planner_failures' is neither null nor a count"),
    ("`planner_failures` true", edit(put("planner_failures", True)), "'planner_failures' is neither null nor a count"),
]


@pytest.mark.parametrize("where", [1, -1], ids=["a middle line", "the last line, whole"])
@pytest.mark.parametrize("name, damage, says", DAMAGED, ids=[case[0] for case in DAMAGED])
def test_a_damaged_line_is_refused_in_one_line(kept, tmp_path, capsys, where, name, damage, says):
    lines = kept.lines
    lines[where] = damage(lines[where])
    n = where % len(lines) + 1
    resume_refused(kept, tmp_path, joined(lines), capsys, f"line {n}", says)


TAMPERED = [
    ("a distance", put("distances", 100, 0, 12.5)),
    ("an ego speed", put("ego", 100, 3, 7.25)),
    ("a distance made null (the agent absent)", put("distances", 100, 0, None)),
    ("planner_failures", put("planner_failures", 0)),
    ("inconclusive", put("inconclusive", "frame 3: planner raised RuntimeError: x")),
]


@pytest.mark.parametrize("name, change", TAMPERED, ids=[case[0] for case in TAMPERED])
def test_a_value_edited_by_hand_is_refused(kept, tmp_path, capsys, name, change):
    """Each edit leaves a line of the right shape: the chain is what tells it was edited."""
    lines = kept.lines
    before = lines[2]
    lines[2] = edit(change)(lines[2])
    assert lines[2] != before
    resume_refused(kept, tmp_path, joined(lines), capsys, "line 3 was changed after it was written")


def test_reordered_lines_are_refused(kept, tmp_path, capsys):
    lines = kept.lines
    lines[1], lines[2] = lines[2], lines[1]
    resume_refused(kept, tmp_path, joined(lines), capsys, "line 2 was changed after it was written, moved")


def test_a_line_left_out_is_refused(kept, tmp_path, capsys):
    lines = kept.lines
    del lines[4]
    resume_refused(kept, tmp_path, joined(lines), capsys, "line 5 was changed after it was written, moved")


def test_a_line_of_another_attacks_checkpoint_is_refused(kept, tmp_path, capsys):
    """Seed 1's first rollout (the ground truth) is seed 0's to the last digit: only its chain, bound to
    the other attack's params, tells it apart."""
    other = write_params(tmp_path / "other.yaml", REPO, seed=1, **SHORT)
    output = tmp_path / "other-out"
    run = _attack(other, "--output", str(output))
    rollouts = checkpoint_folder(output) / ROLLOUTS
    deadline = time.monotonic() + 120
    while not (rollouts.exists() and rollouts.read_bytes().count(b"\n")) and time.monotonic() < deadline:
        time.sleep(0.05)
    run.kill()
    run.wait(timeout=60)
    theirs = json.loads(rollouts.read_bytes().splitlines()[0])
    lines = kept.lines
    ours = json.loads(lines[0])
    assert theirs.pop("chain") != ours.pop("chain") and theirs == ours
    lines[0] = rollouts.read_bytes().splitlines()[0]
    folder = tmp_path / "spliced"
    folder.mkdir()
    resume_refused(kept, folder, joined(lines), capsys, "line 1", "comes from another attack's checkpoint")


def test_a_torn_last_line_is_dropped_and_the_attack_ends_with_the_uninterrupted_report(kept, tmp_path):
    lines = kept.lines
    data = joined(lines[:-1]) + lines[-1][: len(lines[-1]) // 2]  # a kill mid-write: no newline
    output = resume_with(kept, tmp_path, data)
    assert main(["attack", str(kept.params), "--resume", str(output), "--quiet"]) == 0
    assert _report(output) == kept.report
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no checkpoint, no lock


@pytest.mark.parametrize("name, make, says", [
    ("the checkpoint folder a file", lambda c: shutil.rmtree(c) or c.write_text("x"), "not a folder"),
    ("params.json missing", lambda c: (c / "params.json").unlink(), "params.json: missing or not a regular file"),
    ("params.json a folder", lambda c: (c / "params.json").unlink() or (c / "params.json").mkdir(),
     "params.json: missing or not a regular file"),
    ("params.json a FIFO (it would block)", lambda c: (c / "params.json").unlink() or os.mkfifo(c / "params.json"),
     "params.json: missing or not a regular file"),
    ("rollouts.jsonl a folder", lambda c: (c / ROLLOUTS).unlink() or (c / ROLLOUTS).mkdir(),
     "rollouts.jsonl: missing or not a regular file"),
])
def test_a_checkpoint_of_the_wrong_shape_is_refused_in_one_line(kept, tmp_path, capsys, name, make, says):
    output = tmp_path / "out"
    shutil.copytree(kept.checkpoint, checkpoint_folder(output))
    make(checkpoint_folder(output))
    refused(["attack", str(kept.params), "--resume", str(output), "--quiet"], capsys, says,
            f"delete {checkpoint_folder(output)}")


def test_a_second_attack_on_a_running_attacks_output_ends_in_one_line_and_touches_nothing(tmp_path, capsys):
    params = write_params(tmp_path / "p.yaml", REPO, **{"search.random.steps": 1000})  # minutes of search
    output = tmp_path / "out"
    first = _attack(params, "--output", str(output))
    try:
        rollouts = checkpoint_folder(output) / ROLLOUTS
        deadline = time.monotonic() + 120
        while not (rollouts.exists() and rollouts.stat().st_size) and time.monotonic() < deadline:
            time.sleep(0.05)
        kept = {p.name: p.read_bytes() for p in checkpoint_folder(output).iterdir()}
        for flags in (["--output", str(output)], ["--resume", str(output)]):
            refused(["attack", str(params), *flags, "--quiet"], capsys,
                    f"{output}: another attack is running on this output")
        assert first.poll() is None, "the first attack ended before the second was tried"
        now = {p.name: p.read_bytes() for p in checkpoint_folder(output).iterdir()}
        assert now.keys() == kept.keys() and now["params.json"] == kept["params.json"]
        assert now[ROLLOUTS].startswith(kept[ROLLOUTS])  # only the first attack's own appends
        assert not output.exists() and output_lock(output).exists()
    finally:
        first.send_signal(signal.SIGKILL)
        first.wait(timeout=60)
    with exclusive(output_lock(output), "still held"):  # the kernel let go of the killed attack's lock
        pass


def test_an_attack_that_finished_into_the_output_while_this_one_waited_for_its_lock_is_not_overwritten(
        tmp_path, capsys, monkeypatch):
    """The output is checked again once the lock is held: the attack that held it may have written it."""
    params = write_params(tmp_path / "p.yaml", REPO, **SHORT)
    output = tmp_path / "out"
    locked = application.exclusive

    @contextmanager
    def finished_meanwhile(lock: Path, busy: str) -> Iterator[None]:
        output.mkdir()  # the results of the attack that held the lock until now
        with locked(lock, busy):
            yield

    monkeypatch.setattr(application, "exclusive", finished_meanwhile)
    refused(["attack", str(params), "--output", str(output), "--quiet"], capsys, f"{output}: output folder exists already")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "p.yaml"]  # no checkpoint, no lock


def test_a_lock_file_removed_while_it_was_being_taken_is_taken_anew(tmp_path, monkeypatch):
    """The run that held the lock ended (and removed its file) between this one's open and flock: the
    lock this one got guards nothing, so it locks a file of its own."""
    lock = tmp_path / ".out.lock"
    flock, held = fcntl.flock, []

    def the_holder_ends_first(fd: int, operation: int) -> None:
        flock(fd, operation)
        if not held:
            lock.unlink()
        held.append(os.fstat(fd).st_ino)

    monkeypatch.setattr(fcntl, "flock", the_holder_ends_first)
    with exclusive(lock, "busy"):
        assert len(held) == 2 and os.stat(lock).st_ino == held[-1]
    assert not lock.exists()


def test_a_resume_rolls_an_inconclusive_rollout_out_again_and_drops_what_followed(tmp_path):
    """A planner that had died or a node that went silent gave no verdict: a resume must not report on that
    rollout, nor on what the search decided after it, so the checkpoint keeps only the rollouts before it."""
    from advperc_ros.configs import core_configs
    from advperc_ros.core.perception_errors import PerceptionErrors
    from advperc_ros.core.rollout import RolloutResult
    from advperc_ros.params import load_params, resolve_bag
    from advperc_ros.ros.bag import read_scenario

    params = load_params(REPO / "config" / "idm_lane_following.yaml")
    scenario, canonical = read_scenario(resolve_bag(params)), core_configs(params).canonical
    output = tmp_path / "out"
    frames, agents = 3, scenario.agents.shape[1]

    def result(inconclusive: str | None) -> RolloutResult:
        return RolloutResult(ego=np.zeros((frames, 4)), distances=np.ones((frames, agents)), inconclusive=inconclusive)

    errors = [PerceptionErrors.none(*scenario.agents.shape)] * 4
    written = Checkpoint(output, canonical, scenario, resume=False)
    for e, verdict in zip(errors, (None, None, "frame 2: planner raised RuntimeError: died", None)):
        written.append(e, result(verdict))
    written.close(finished=False)
    resumed = Checkpoint(output, canonical, scenario, resume=True)
    assert [stored.result.inconclusive for stored in resumed.done] == [None, None]
    resumed.close(finished=False)
    assert (checkpoint_folder(output) / ROLLOUTS).read_bytes().count(b"\n") == 2
    again = Checkpoint(output, canonical, scenario, resume=True)  # the file it left resumes as it was
    assert len(again.done) == 2
    again.close(finished=False)
