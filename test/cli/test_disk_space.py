"""A full disk never costs a search: an output whose disk cannot hold the run's estimate is refused
before any work, and a disk that fills during the run stops it with one line, the checkpoint kept,
so that `--resume` after freeing space writes the report an uninterrupted run writes."""

import errno
import json
import shutil
import subprocess
import sys
import time
from collections import namedtuple
from pathlib import Path

import numpy as np
import pytest

from advperc_ros.application import output_bytes
from advperc_ros.backends.resumed import Checkpoint, checkpoint_folder
from advperc_ros.cli import main
from advperc_ros.configs import core_configs
from advperc_ros.core.search.config import budget
from advperc_ros.params import load_params
from advperc_ros.ros.bag import read_scenario
from conftest import REPO
from test_cli import write_params

Usage = namedtuple("Usage", "total used free")


def _report(folder: Path) -> dict:
    return {k: v for k, v in json.loads((folder / "report.json").read_text()).items() if k != "wall_time_s"}


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    base = tmp_path_factory.mktemp("space")
    params = write_params(base / "p.yaml", REPO)
    assert main(["attack", str(params), "--output", str(base / "whole"), "--quiet"]) == 0
    return params, _report(base / "whole"), base / "whole"


def test_a_disk_without_room_for_the_estimate_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    params = write_params(tmp_path / "p.yaml", REPO)
    monkeypatch.setattr("advperc_ros.results.destination.shutil.disk_usage", lambda place: Usage(10 * 2**20, 9 * 2**20, 2**20))
    before = sorted(tmp_path.rglob("*"))
    assert main(["attack", str(params), "--output", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(tmp_path / "out") in err and "1.0 MiB free" in err, err
    assert sorted(tmp_path.rglob("*")) == before


def test_a_disk_that_fills_mid_search_keeps_the_checkpoint_and_resume_gives_the_uninterrupted_report(
        uninterrupted, tmp_path, capsys, monkeypatch):
    params, expected, whole = uninterrupted
    output = tmp_path / "out"
    append = Checkpoint.append
    calls = []

    def fills_at_the_fourth(self, errors, result):
        calls.append(1)
        if len(calls) == 4:
            raise OSError(errno.ENOSPC, "No space left on device")
        append(self, errors, result)

    monkeypatch.setattr(Checkpoint, "append", fills_at_the_fourth)
    assert main(["attack", str(params), "--output", str(output), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "the disk filled" in err and f"--resume {output}" in err, err
    assert not output.exists()
    lines = (checkpoint_folder(output) / "rollouts.jsonl").read_text().splitlines()
    assert len(lines) == 3
    _estimate_covers(params, whole, max(len(line) + 1 for line in lines))
    monkeypatch.undo()
    assert main(["attack", str(params), "--resume", str(output), "--quiet"]) == 0
    assert _report(output) == expected
    assert not checkpoint_folder(output).exists()


def _estimate_covers(params: Path, results: Path, checkpoint_line: int) -> None:
    """Generous, not tight: the results folder and a checkpoint line for every rollout the search may run."""
    loaded = load_params(params)
    bag = REPO / "bags" / "idm_lane_following"
    scenario = read_scenario(bag)
    search = core_configs(loaded).search
    written = sum(p.stat().st_size for p in results.rglob("*") if p.is_file())
    bound = budget(search, scenario.agents.shape[1], joint=True, approach=True)
    estimate = output_bytes(scenario, search, bag)
    assert written + bound * checkpoint_line <= estimate < 50 * 2**20, (written, bound, checkpoint_line, estimate)


def test_an_error_of_the_disk_that_is_not_a_full_one_stays_a_bug(tmp_path, monkeypatch):
    """Only ENOSPC and EDQUOT are the user's to fix by freeing space; EIO (say) keeps its traceback."""
    params = write_params(tmp_path / "p.yaml", REPO)

    def broken(self, errors, result):
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(Checkpoint, "append", broken)
    with pytest.raises(OSError, match="Input/output"):
        main(["attack", str(params), "--output", str(tmp_path / "out"), "--quiet"])


@pytest.fixture
def small_disk(tmp_path):
    """A 40 MiB tmpfs: a real disk that fills (needs the right to mount, as root in CI has)."""
    mount = tmp_path / "disk"
    mount.mkdir()
    made = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=40m", "tmpfs", str(mount)], capture_output=True)
    if made.returncode:
        pytest.skip(f"cannot mount a tmpfs here: {made.stderr.decode().strip()}")
    yield mount
    subprocess.run(["umount", "-l", str(mount)], check=True)


def test_a_real_disk_filled_by_another_program_mid_search(uninterrupted, small_disk):
    """Another program fills the disk once the first rollout is checkpointed: one line, exit 2, the
    checkpoint kept; once the filler is gone, --resume writes the uninterrupted report."""
    params, expected, _ = uninterrupted
    output = small_disk / "out"
    run = subprocess.Popen([sys.executable, "-m", "advperc_ros.cli", "attack", str(params), "--output", str(output),
                            "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    rollouts = checkpoint_folder(output) / "rollouts.jsonl"
    deadline = time.monotonic() + 120
    while not (rollouts.exists() and rollouts.stat().st_size) and run.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    filler = small_disk / "filler"
    with filler.open("wb") as handle:
        try:
            while True:
                handle.write(bytes(1 << 20))
                handle.flush()
        except OSError as exc:
            assert exc.errno == errno.ENOSPC
    _, err = run.communicate(timeout=300)
    if run.returncode == 0:
        pytest.fail("the attack finished before the disk was full: give it a longer search")
    assert run.returncode == 2 and len(err.strip().splitlines()) == 1 and "the disk filled" in err, err
    assert rollouts.stat().st_size and not output.exists()
    filler.unlink()
    assert main(["attack", str(params), "--resume", str(output), "--quiet"]) == 0
    assert _report(output) == expected
    assert sorted(p.name for p in small_disk.iterdir()) == ["out"]
    shutil.rmtree(output)


def _detector_log(path: Path) -> Path:
    """A bag of a detector's output: a scene of five cars detected with the errors the extended model samples (an
    attack bag's detections copy the truth, which pem fit refuses)."""
    from pem_scenes import EXTENDED, moving_scene

    from advperc_ros.core.perception_errors import inject
    from advperc_ros.core.scenario import EgoState
    from advperc_ros.ros import messages as msgs
    from advperc_ros.ros import topics
    from advperc_ros.ros.bag import open_bag_for_writing

    rng = np.random.default_rng(0)
    truth, ego = moving_scene(rng)
    detected = inject(truth, EXTENDED.sample(truth, ego, rng))
    with open_bag_for_writing(path) as bag:
        for k in range(truth.shape[0]):
            ns = 100_000_000 * (k + 1)
            bag.write(topics.GROUND_TRUTH, ns, msgs.objects_to_markers(truth.frame(k), ns, "ground_truth"))
            bag.write(topics.PERCEPTION, ns, msgs.objects_to_markers(detected.frame(k), ns, "perception"))
            bag.write(topics.ODOMETRY, ns, msgs.odometry(EgoState(ego[k, 0], ego[k, 1], 0.0, 8.0), ns))
    return path


def test_pem_fit_makes_the_missing_folders_of_its_output(tmp_path):
    """`check_output` lets an output's folders be missing (they are made); pem fit failed on it after the fit."""
    model = tmp_path / "models" / "new" / "m.json"
    assert main(["pem", "fit", str(_detector_log(tmp_path / "log")), "--output", str(model)]) == 0
    assert json.loads(model.read_text())["source"]
    assert sorted(p.name for p in model.parent.iterdir()) == ["m.json"]


@pytest.fixture
def read_only(tmp_path, uninterrupted):
    """A copy of a results folder, mounted read-only onto itself (as a results folder on a read-only
    share is; root passes access() checks but not a read-only mount)."""
    _, _, whole = uninterrupted
    folder = tmp_path / "results"
    shutil.copytree(whole, folder)
    for step in (["mount", "--bind", str(folder), str(folder)], ["mount", "-o", "remount,ro,bind", str(folder)]):
        made = subprocess.run(step, capture_output=True)
        if made.returncode:
            subprocess.run(["umount", str(folder)], capture_output=True)
            pytest.skip(f"cannot mount read-only here: {made.stderr.decode().strip()}")
    yield folder
    subprocess.run(["umount", "-l", str(folder)], check=True)


def test_robustness_into_a_read_only_results_folder_is_refused_before_its_rollouts(read_only, capsys, monkeypatch):
    monkeypatch.setattr("advperc_ros.core.robustness.robustness_curve", lambda *a, **k: pytest.fail("rollouts ran"))
    assert main(["robustness", str(read_only), "--samples", "2"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(read_only) in err and "not writable" in err, err
