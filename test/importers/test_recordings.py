"""Every CommonRoad recording, attacked through the CLI: the contract of each outcome (README,
"Recorded traffic (CommonRoad)").

- an attack found is a collision the ego is at fault for, and its ground-truth rollout has none;
- no attack: report.json says why, including what hiding every vehicle does;
- refused (exit 1): the planner collides at fault with perfect perception, said on stderr;
- rejected (exit 3, import): the reason is on stderr and nothing is written.

All 24 recordings with both bundled planners take over an hour (ObP: minutes per recording), so by
default this runs three small ones with IDM (a few minutes); ADVPERC_ALL_RECORDINGS=1 runs the lot,
as benchmarks/recordings_bench.py does. Each also runs with its traffic 0.5 s earlier
(`shift_traffic`): a recording no rule of the tool was written or measured on, which must keep the
same contracts. Skips with a reason without the data or commonroad-io.
"""

import json
import os
from pathlib import Path

import pytest
import yaml

from conftest import REPO

from advperc_ros.backends.embedded import Stack
from advperc_ros.cli import main
from advperc_ros.configs import core_configs
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.params import load_params
from advperc_ros.results.folder import load_errors
from advperc_ros.ros.bag import read_scenario

DATA = REPO.parent / "shared" / "data" / "commonroad"
EVERYTHING = os.environ.get("ADVPERC_ALL_RECORDINGS") == "1"
SMALL = ("USA_US101-1_1_T-1", "USA_Peach-3_2_T-1", "USA_Lanker-1_6_T-1")  # 2, 8, 34 vehicles; 1 s to 6 s
RECORDINGS = sorted(p.stem for p in DATA.glob("*.xml")) if EVERYTHING and DATA.is_dir() else list(SMALL)
PLANNERS = ("idm", "obp") if EVERYTHING else ("idm",)
SHIFTS = (0.0, 0.5)  # s the traffic is moved earlier (0: as published; USA_Lanker-1_6 lasts 1 s)

pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason=f"CommonRoad recordings not found at {DATA}")


@pytest.fixture(scope="module")
def commonroad():
    return pytest.importorskip("commonroad", reason="commonroad-io is not installed (pip install '.[commonroad]')")


def _import(name: str, shift: float, folder: Path, capsys) -> tuple[Path | None, int, str]:
    source = DATA / f"{name}.xml"
    if shift:  # the same road at another moment, written beside what the commands write
        from advperc_ros.importers.commonroad import shift_traffic

        (folder / "source").mkdir()
        shifted = folder / "source" / f"{name}+{shift:g}s.xml"
        shift_traffic(source, shifted, shift)
        source = shifted
    capsys.readouterr()
    code = main(["import-commonroad", str(source), "--output", str(folder / "bag")])
    return (folder / "bag" if code == 0 else None), code, capsys.readouterr().err


@pytest.mark.parametrize("shift", SHIFTS)
@pytest.mark.parametrize("planner", PLANNERS)
@pytest.mark.parametrize("name", RECORDINGS)
def test_a_recording_is_attacked_or_says_why_not(name, planner, shift, tmp_path, capsys, commonroad):
    bag, code, err = _import(name, shift, tmp_path, capsys)
    if code == 3:
        assert "rejected, not attacked: recorded traffic hits the ego whatever it does" in err
        assert not any(path.name != "source" for path in tmp_path.iterdir())
        return
    assert code == 0, err
    params_path = tmp_path / ("bag.yaml" if planner == "idm" else f"bag.{planner}.yaml")
    document = yaml.safe_load(params_path.read_text())
    assert document["orchestrator"]["ros__parameters"]["rule"] == {"name": "at_fault_collision"}

    code = main(["attack", str(params_path), "--output", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err
    params = load_params(params_path)
    scenario = read_scenario(bag)
    truth = Stack(scenario, core_configs(params)).rollout(PerceptionErrors.none(*scenario.agents.shape))
    if code == 1:  # refused: the planner collides at fault unattacked
        assert "already collides with perfect perception" in err and truth.collided
        return
    assert code == 0, err
    assert not truth.collided  # what was attacked had no at-fault collision to begin with
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    if report["collision"]:
        attacked = Stack(scenario, core_configs(params)).rollout(load_errors(tmp_path / "out" / "attack_errors.npz"))
        # at fault: with rule.at_fault_only, excused contacts (rear-ended, hit while stopped) do not count
        assert attacked.collided and attacked.excused is not None
        assert report["nds"] is not None and report["nds_t"] is not None
    else:
        assert report["message"].startswith("no collision found")
        assert report["blind"] is not None and "every vehicle hidden" in report["message"]
        # the at-fault margin leaves out near misses a contact at which would be excused
        assert report["blind"]["margin"] >= max(report["blind"]["min_signed_distance"], 0.0)

