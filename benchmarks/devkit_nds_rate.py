"""Time the real nuscenes-devkit 1.2.0 NDS evaluation on the first case of a case file.

Must be run with the devkit venv's python (the devkit pins numpy<2, so it never goes
into the project's main environment).  From the repository root::

    python3 -m venv .venv-devkit
    .venv-devkit/bin/pip install nuscenes-devkit==1.2.0 'numpy<2'
    .venv-devkit/bin/python benchmarks/devkit_nds_rate.py test/fixtures/nds/devkit_cases.json

argv[1] is a JSON file in the case format of test/fixtures/nds/devkit_cases.json (a list
of cases; a single case object is accepted too; the "devkit" entry is not needed).
Prints one JSON line: {"evals_per_s": ..., "evals_per_cpu_s": ..., "nds": ...}; the second rate
counts this process's CPU time, which other load on a shared machine barely changes.

What is timed: one full evaluation = building fresh EvalBoxes from the (pre-built)
DetectionBox lists + devkit ``filter_eval_boxes`` on gt and preds +
``DetectionEval.evaluate()``.  Not timed: reading/parsing the JSON and constructing the
DetectionBox objects (the devkit's own pipeline does that in its loaders).  Repeats for
at least 1 s (wall) and at least 3 evaluations.  The devkit glue (config restriction to 'car',
nusc stub, empty-set filter workaround) is imported from
test/fixtures/nds/make_devkit_fixtures.py so both use the identical code path.
"""

import importlib.util
import json
import os
import sys
import time

MIN_SECONDS = 1.0
MIN_EVALS = 3


def _load_fixture_module():
    here = os.path.dirname(os.path.abspath(__file__))
    path = os.path.join(here, os.pardir, "test", "fixtures", "nds", "make_devkit_fixtures.py")
    spec = importlib.util.spec_from_file_location("make_devkit_fixtures", os.path.normpath(path))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def main(argv):
    if len(argv) != 2:
        print(f"usage: {argv[0]} CASES.json", file=sys.stderr)
        return 2
    fx = _load_fixture_module()
    with open(argv[1]) as f:
        data = json.load(f)
    case = data if isinstance(data, dict) else data[0]

    cfg = fx.make_config()
    gt_lists, pred_lists = fx.build_box_lists(case)
    nusc = fx.NuscStub()

    # Warm-up (imports, first-call overheads), not timed.
    metrics, _ = fx.evaluate_box_lists(cfg, gt_lists, pred_lists, nusc)
    nds = float(metrics.nd_score)

    n = 0
    t0, cpu0 = time.perf_counter(), time.process_time()
    while True:
        metrics, _ = fx.evaluate_box_lists(cfg, gt_lists, pred_lists, nusc)
        n += 1
        elapsed = time.perf_counter() - t0
        if n >= MIN_EVALS and elapsed >= MIN_SECONDS:
            break
    cpu = time.process_time() - cpu0
    assert float(metrics.nd_score) == nds
    print(json.dumps({"evals_per_s": n / elapsed, "evals_per_cpu_s": n / cpu, "nds": nds}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
