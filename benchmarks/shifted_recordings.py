"""Recordings the project has never seen, made from the ones it has: the same road and planning
problem, the recorded traffic of another moment.

    python benchmarks/shifted_recordings.py --shift 1.0 --output DIR
    python benchmarks/recordings_bench.py --data DIR --planners idm obp --keep DIR/runs --markdown

Every vehicle of each CommonRoad recording is moved `--shift` seconds earlier (the ego meets the
traffic that passed its start point `--shift` s after the recorded car it replaces did): vehicles
gone by then are dropped, the others start from their first state at or after that moment. The ego,
the map and the goal are the file's own. The tool's rules were written and measured on the
recordings as published, so these are a held-out set for the same commands (README, "Recorded
traffic"): each must end in one of the documented outcomes, with its contract.
"""

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))  # this checkout, not whichever advperc_ros is installed
DATA = REPO.parent / "shared" / "data" / "commonroad"

from advperc_ros.importers.commonroad import shift_traffic  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=DATA, help="folder of CommonRoad XML files")
    parser.add_argument("--shift", type=float, default=1.0, help="seconds the traffic is moved earlier")
    parser.add_argument("--output", type=Path, required=True, help="folder to write the shifted recordings to")
    args = parser.parse_args()
    sources = sorted(args.data.glob("*.xml"))
    if not sources:
        sys.exit(f"{args.data}: no CommonRoad recordings")
    args.output.mkdir(parents=True, exist_ok=True)
    for source in sources:
        target = args.output / f"{source.stem}+{args.shift:g}s.xml"
        print(f"{target.name}: {shift_traffic(source, target, args.shift)} vehicles")


if __name__ == "__main__":
    main()
