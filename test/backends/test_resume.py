"""Nothing lost: a killed attack resumes to the report an uninterrupted one writes."""

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from advperc_ros.backends.resumed import checkpoint_folder
from conftest import REPO
from test_cli import write_params

WALL_CLOCK = ("wall_time_s",)


def _report(folder: Path) -> dict:
    return {k: v for k, v in json.loads((folder / "report.json").read_text()).items() if k not in WALL_CLOCK}


def _attack(params: Path, *flags: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "advperc_ros.cli", "attack", str(params), "--quiet", *flags],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)


def _wait_for_a_checkpointed_rollout(run: subprocess.Popen, output: Path) -> None:
    """Until the attack has checkpointed a rollout (before, there is nothing to keep), or ended."""
    rollouts = checkpoint_folder(output) / "rollouts.jsonl"
    deadline = time.monotonic() + 120
    while not (rollouts.exists() and rollouts.stat().st_size) and run.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    base = tmp_path_factory.mktemp("resume")
    params = write_params(base / "p.yaml", REPO)
    run = _attack(params, "--output", str(base / "whole"))
    _, err = run.communicate(timeout=600)
    assert run.returncode == 0, err
    return params, _report(base / "whole")


def _kept_rollouts(output: Path) -> int:
    """Whole lines of the checkpoint: the rollouts a resume will not run again."""
    rollouts = checkpoint_folder(output) / "rollouts.jsonl"
    return rollouts.read_text().count("\n") if rollouts.exists() else 0


def _kill_at(run: subprocess.Popen, output: Path, rollouts: int) -> None:
    """SIGKILL once the attack has checkpointed `rollouts` rollouts in all (at once when it holds that
    many already: a kill while it starts and reads its checkpoint), or once it has ended."""
    deadline = time.monotonic() + 120
    while _kept_rollouts(output) < rollouts and run.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    run.send_signal(signal.SIGKILL)
    run.wait(timeout=60)


def test_sigkill_ten_times_over_one_attack_then_resume_gives_the_uninterrupted_report(uninterrupted, tmp_path):
    """Killed at a random rollout of the search ten times over (the first run after its first rollout, a
    resumed run at times while it starts), whatever the machine's speed: no kill loses a checkpointed
    rollout, and the resume after the last one writes the uninterrupted report."""
    params, expected = uninterrupted
    output = tmp_path / "run"
    draw = random.Random(12)
    kept = 0
    for n in range(10):
        run = _attack(params, *(("--resume", str(output)) if n else ("--output", str(output))))
        target = min(kept + draw.randint(0 if n else 1, max(1, expected["rollouts"] // 8)), expected["rollouts"] - 1)
        _kill_at(run, output, target)
        if output.exists():  # it finished before this kill
            break
        now = _kept_rollouts(output)
        assert now >= kept, f"kill {n + 1}, at rollout {target}, lost rollouts"
        kept = now
    else:
        resumed = _attack(params, "--resume", str(output))
        _, err = resumed.communicate(timeout=600)
        assert resumed.returncode == 0, err
    assert kept > 0  # the kills landed inside the search, not all before its first rollout
    assert _report(output) == expected
    assert not checkpoint_folder(output).exists()
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(f".{output.name}.")]  # no debris


def test_ctrl_c_is_one_line_exit_130_and_the_attack_can_be_finished(uninterrupted, tmp_path):
    params, expected = uninterrupted
    output = tmp_path / "out"
    run = _attack(params, "--output", str(output))
    _wait_for_a_checkpointed_rollout(run, output)
    run.send_signal(signal.SIGINT)
    _, err = run.communicate(timeout=60)
    if run.returncode == 0:
        pytest.skip("the attack finished before the interrupt")
    assert run.returncode == 130 and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert f"--resume {output}" in err and not output.exists() and checkpoint_folder(output).is_dir()
    again = _attack(params, "--output", str(output))  # not silently started afresh over a checkpoint
    _, err = again.communicate(timeout=60)
    assert again.returncode == 2 and "--resume" in err
    resumed = _attack(params, "--resume", str(output))
    _, err = resumed.communicate(timeout=600)
    assert resumed.returncode == 0, err
    assert _report(output) == expected


def test_a_checkpoint_only_finishes_its_own_attack(uninterrupted, tmp_path):
    params, _ = uninterrupted
    output = tmp_path / "out"
    run = _attack(params, "--output", str(output))
    _wait_for_a_checkpointed_rollout(run, output)
    os.kill(run.pid, signal.SIGKILL)
    run.wait(timeout=60)
    if output.exists():
        pytest.skip("the attack finished before the kill")
    other = write_params(tmp_path / "other.yaml", REPO, seed=5)
    resumed = _attack(other, "--resume", str(output))
    _, err = resumed.communicate(timeout=60)
    assert resumed.returncode == 2 and "other params" in err


def test_an_attack_killed_among_its_phantom_obstacles_resumes_to_the_uninterrupted_report(tmp_path):
    """With every error kind on, the phantom obstacles roll out after the drops: a kill once the first
    of them is checkpointed loses none, and the resume writes the uninterrupted report. The budget ends the
    search two rollouts after them (idm_lane_following: 12 rollouts of drops, then the 8 phantoms)."""
    params = write_params(tmp_path / "p.yaml", REPO, **{"search.budget": 22})
    whole = _attack(params, "--errors", "all", "--output", str(tmp_path / "whole"))
    _, err = whole.communicate(timeout=600)
    assert whole.returncode == 0, err
    phases = [line.split(",")[1] for line in (tmp_path / "whole" / "search_log.csv").read_text().splitlines()[1:]]
    first_phantom = phases.index("phantom")
    output = tmp_path / "run"
    run = _attack(params, "--errors", "all", "--output", str(output))
    deadline = time.monotonic() + 300
    while _kept_rollouts(output) <= first_phantom and run.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    run.send_signal(signal.SIGKILL)
    run.wait(timeout=60)
    assert not output.exists() and _kept_rollouts(output) > first_phantom  # killed after a phantom, before the end
    resumed = _attack(params, "--errors", "all", "--resume", str(output))
    _, err = resumed.communicate(timeout=600)
    assert resumed.returncode == 0, err
    assert _report(output) == _report(tmp_path / "whole")


def test_a_reactive_attack_killed_mid_search_resumes_to_the_uninterrupted_report(tmp_path):
    """Under reactive traffic the checkpoint holds the ego's states only; the resumed rollouts' agents are rebuilt
    from them (`traffic.simulate`), so the report is the uninterrupted one, agents that reacted and all."""
    params = write_params(tmp_path / "p.yaml", REPO)
    whole = _attack(params, "--reactive", "--output", str(tmp_path / "whole"))
    _, err = whole.communicate(timeout=600)
    assert whole.returncode == 0, err
    output = tmp_path / "out"
    run = _attack(params, "--reactive", "--output", str(output))
    _kill_at(run, output, 6)
    if output.exists():
        pytest.skip("the attack finished before the kill")
    resumed = _attack(params, "--reactive", "--resume", str(output))
    _, err = resumed.communicate(timeout=600)
    assert resumed.returncode == 0, err
    expected = _report(tmp_path / "whole")
    assert _report(output) == expected and expected["traffic"] == "reactive"
