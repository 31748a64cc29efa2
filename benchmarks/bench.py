"""Speed of the pipeline, measured side by side in one run (the machine is shared: compare ratios).

    python benchmarks/bench.py            # everything
    python benchmarks/bench.py --quick    # fewer repetitions; IDM searches with one objective, both methods
    python benchmarks/bench.py --sections 3 --scenarios obp_right_turn   # one scenario's searches

1. Rollout: full rollout time against the planner alone (the floor): CPU time against the CPU time
   of the rollout's own plan() calls (the issue-13 ratio, goal <= 1.5 for IDM), and wall time
   against its "planner" stage (plan() plus following the plan); the time per stage, and the
   median and 95th percentile of one planning call.
2. NDS: evaluations per second of ours against nuscenes-devkit 1.2.0 on the same 200-frame,
   5-car input, by CPU time of each process (other load on a shared machine cancels out) and by
   wall time. The devkit pins numpy<2 and runs from its own venv (created on first use at
   .venv-devkit, or pass --devkit-python); both NDS values are printed to show they agree.
3. A whole search at the default budget per scenario, objective and method (the default, guided, and the
   paper's: heuristic + 40 random steps + refine; README Table 1's rows): wall time, the metric
   reached and the perception scores of the best attack (paper Table 1's columns).
4. Recorded traffic (every CommonRoad recording in ../shared/data/commonroad, when present, 2 to 83
   vehicles; --quick: every third): per-frame rollout cost and whole-search wall time against the
   number of recorded vehicles, with the params import-commonroad writes: per frame for IDM and ObP,
   the whole search by the paper's method for IDM (an ObP search takes minutes:
   benchmarks/recordings_bench.py; the guided search on every recording: its --method guided).
"""

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))  # time this checkout, not whichever advperc_ros is installed

from advperc_ros.application import run_attack  # noqa: E402
from advperc_ros.backends.embedded import Stack  # noqa: E402
from advperc_ros.configs import core_configs  # noqa: E402
from advperc_ros.core.perception_errors import PerceptionErrors, inject  # noqa: E402
from advperc_ros.core.search.registry import METHODS  # noqa: E402
from advperc_ros.core.search.problem import OBJECTIVES  # noqa: E402
from advperc_ros.exceptions import GroundTruthFails  # noqa: E402
from advperc_ros.core.metrics.nds import nds  # noqa: E402
from advperc_ros.core.rollout import STAGES  # noqa: E402
from advperc_ros.core.typical import TypicalErrorConfig, sample_typical_errors  # noqa: E402
from advperc_ros.params import load_params  # noqa: E402
from advperc_ros.ros.bag import read_scenario  # noqa: E402

IDM_SCENARIOS = ("idm_lane_following", "idm_overtake_follow")
OBP_SCENARIOS = ("obp_overtake", "obp_left_turn", "obp_right_turn")
SCENARIOS = IDM_SCENARIOS + OBP_SCENARIOS
DEVKIT_VENV = REPO / ".venv-devkit"
COMMONROAD = REPO.parent / "shared" / "data" / "commonroad"


class TimedPlanner:
    """Any planner, with the wall and CPU time of each planning call recorded."""

    def __init__(self, planner) -> None:
        self.planner, self.call_times, self.call_cpu = planner, [], []

    def reset(self) -> None:
        self.planner.reset()

    def plan(self, t, ego, tracks):
        started, cpu = time.perf_counter(), time.thread_time()
        plan = self.planner.plan(t, ego, tracks)
        self.call_cpu.append(time.thread_time() - cpu)
        self.call_times.append(time.perf_counter() - started)
        return plan


def bench_rollouts(repeats: int, obp_repeats: int) -> None:
    """Each rollout's CPU time against the CPU time of its own plan() calls (what the planner alone
    costs; other load on the machine cancels out of the ratio), and its wall time against its
    "planner" stage (plan() plus following the plan and arming the plan alarm)."""
    print(f"== 1. Rollout time vs planner-only time (ground-truth rollouts, median of {repeats}, ObP {obp_repeats}) ==")
    print(f"{'scenario':24s} {'frames':>6s} {'CPU ms':>7s} {'plan()':>7s} {'ratio':>6s} {'wall ms':>7s} "
          f"{'stage':>7s} {'ratio':>6s} {'step p50':>8s} {'step p95':>8s}  per stage (wall ms)")
    for name in SCENARIOS:
        scenario = read_scenario(REPO / "bags" / name)
        stack = Stack(scenario, core_configs(load_params(REPO / "config" / f"{name}.yaml")))
        stack.planner = timed = TimedPlanner(stack.planner)
        errors = PerceptionErrors.none(*scenario.agents.shape)
        cpu, plan_cpu, totals, stages = [], [], [], {stage: [] for stage in STAGES}
        for _ in range(obp_repeats if name in OBP_SCENARIOS else repeats):
            calls = len(timed.call_cpu)
            started, cpu_started = time.perf_counter(), time.thread_time()
            result = stack.rollout(errors)
            cpu.append(time.thread_time() - cpu_started)
            totals.append(time.perf_counter() - started)
            plan_cpu.append(sum(timed.call_cpu[calls:]))
            for stage in STAGES:
                stages[stage].append(result.stage_times[stage])
        ratio = statistics.median(c / p for c, p in zip(cpu, plan_cpu))
        stage_ratio = statistics.median(t / p for t, p in zip(totals, stages["planner"]))
        p50, p95 = np.percentile(timed.call_times, [50, 95]) * 1e3
        per_stage = "  ".join(f"{s} {statistics.median(v) * 1e3:.1f}" for s, v in stages.items())
        print(f"{name:24s} {result.num_frames:6d} {statistics.median(cpu) * 1e3:7.1f} "
              f"{statistics.median(plan_cpu) * 1e3:7.1f} {ratio:6.2f} {statistics.median(totals) * 1e3:7.1f} "
              f"{statistics.median(stages['planner']) * 1e3:7.1f} {stage_ratio:6.2f} {p50:8.2f} {p95:8.2f}  {per_stage}")


def nds_case() -> dict:
    """200 frames, 5 cars of idm_lane_following with typical errors, in the devkit case format."""
    scenario = read_scenario(REPO / "bags" / "idm_lane_following")
    stack = Stack(scenario, core_configs(load_params(REPO / "config" / "idm_lane_following.yaml")))
    truth = scenario.agents.frames(200)
    errors = sample_typical_errors(scenario.agents.shape, np.random.default_rng(7), TypicalErrorConfig(position_std=0.5))
    ego = stack.rollout(PerceptionErrors.none(*scenario.agents.shape)).ego_xy[:200]
    perceived = inject(scenario.agents, errors).frames(200)
    columns = ("ids", "x", "y", "yaw", "length", "width", "height", "vx", "vy")
    frames = []
    for k in range(200):
        gt, pred = truth.frame(k), perceived.frame(k)
        frames.append({
            "ego": ego[k].tolist(),
            "gt": np.stack([gt[c] for c in columns], axis=1).tolist(),
            "pred": np.stack([pred[c] for c in (*columns, "score")], axis=1).tolist(),
        })
    return {"name": "bench_200x5", "frames": frames, "truth": truth, "perceived": perceived, "ego": ego}


def devkit_python(given: str | None) -> Path | None:
    if given:
        return Path(given)
    python = DEVKIT_VENV / "bin" / "python"
    if not python.exists():
        print(f"(creating {DEVKIT_VENV} with nuscenes-devkit 1.2.0; once)", flush=True)
        subprocess.run([sys.executable, "-m", "venv", str(DEVKIT_VENV)], check=True)
        installed = subprocess.run(
            [str(python), "-m", "pip", "install", "-q", "nuscenes-devkit==1.2.0", "numpy<2"], check=False
        )
        if installed.returncode != 0:
            return None
    return python


def bench_nds(min_seconds: float, devkit: str | None) -> None:
    print("\n== 2. NDS evaluations per second, ours vs nuscenes-devkit, same 200-frame 5-car input ==")
    case = nds_case()
    truth, perceived, ego = case.pop("truth"), case.pop("perceived"), case.pop("ego")
    count, started, cpu = 0, time.perf_counter(), time.process_time()
    while time.perf_counter() - started < min_seconds or count < 3:
        ours = nds(truth, perceived, ego).nds
        count += 1
    ours_rate, ours_cpu_rate = count / (time.perf_counter() - started), count / (time.process_time() - cpu)
    python = devkit_python(devkit)
    if python is None:
        print(f"ours: {ours_cpu_rate:10.1f} evals/CPU-s  NDS {ours:.12f}   devkit: unavailable (venv install failed)")
        return
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "case.json"
        path.write_text(json.dumps(case))
        out = subprocess.run(
            [str(python), str(REPO / "benchmarks" / "devkit_nds_rate.py"), str(path)],
            check=True, capture_output=True, text=True,
        )
    ref = json.loads(out.stdout.strip().splitlines()[-1])
    print(f"ours:   {ours_cpu_rate:10.1f} evals/CPU-s {ours_rate:10.1f} evals/s   NDS {ours:.12f}")
    print(f"devkit: {ref['evals_per_cpu_s']:10.1f} evals/CPU-s {ref['evals_per_s']:10.1f} evals/s   NDS {ref['nds']:.12f}")
    print(f"speed-up: {ours_cpu_rate / ref['evals_per_cpu_s']:.0f}x by CPU time, {ours_rate / ref['evals_per_s']:.0f}x by wall time"
          f"   |NDS difference|: {abs(ours - ref['nds']):.2e}")


def bench_searches(scenarios: tuple[str, ...], objectives: tuple[str, ...], methods: tuple[str, ...]) -> None:
    print("\n== 3. Whole search per scenario at the default budget, seed 0 ==")
    print(f"{'scenario':24s} {'objective':9s} {'method':6s} {'rollouts':>8s} {'wall s':>7s} {'s/rollout':>9s} "
          f"{'heuristic':>9s} {'final':>7s} {'NDS':>6s} {'NDS-t':>6s} {'FN/TP':>8s} {'MPE':>5s} {'MAOE':>5s} "
          f"{'PEM LL':>6s} {'failures':>8s}")
    for name in scenarios:
        scenario = read_scenario(REPO / "bags" / name)
        base = load_params(REPO / "config" / f"{name}.yaml")
        for objective in objectives:
            for method in methods:
                params = base.with_values(objective=objective, **{"search.method": method})
                outcome = run_attack(scenario, params, progress=False)
                best, heur = outcome.best, outcome.heuristic_best
                rollouts = len(outcome.log)
                print(f"{name:24s} {objective:9s} {method:6s} {rollouts:8d} {outcome.wall_time_s:7.1f} "
                      f"{outcome.wall_time_s / rollouts:9.3f} {heur.metric:9.4f} {best.metric:7.4f} "
                      f"{best.scores.nds:6.4f} {best.scores.nds_t:6.4f} {best.scores.fn:>4d}/{best.scores.tp:<4d} "
                      f"{best.scores.mpe:5.2f} {best.scores.maoe:5.2f} {best.scores.pem_ll:6.3f} "
                      f"{sum(row.planner_failures or 0 for row in outcome.log):8d}", flush=True)


def bench_recordings(repeats: int, every: int) -> None:
    print("\n== 4. Recorded traffic: cost against the number of vehicles (ms per frame: IDM and ObP; search: IDM, "
          "objective nds_t, the paper's method) ==")
    if not COMMONROAD.is_dir():
        print(f"(skipped: no recordings at {COMMONROAD})")
        return
    from advperc_ros.core.feasibility import unavoidable_collision
    from advperc_ros.importers.commonroad import import_commonroad
    from advperc_ros.params import parse_params

    print(f"{'recording':22s} {'vehicles':>8s} {'frames':>6s} {'ms/frame':>8s} {'tracker':>7s} {'planner':>7s} "
          f"{'rule':>6s} {'ObP ms/frame':>12s} {'ObP planner':>11s} {'search s':>8s} {'rollouts':>8s}  outcome")
    imported_all = [import_commonroad(path) for path in sorted(COMMONROAD.glob("*.xml"))]
    for imported in sorted(imported_all, key=lambda i: i.scenario.agents.shape[1])[::every]:
        scenario = imported.scenario
        name = scenario.name
        frames = scenario.num_frames
        errors = PerceptionErrors.none(*scenario.agents.shape)
        params, per = {}, {}
        for planner, times in (("idm", repeats), ("obp", max(1, repeats // 2))):  # as import-commonroad writes them
            document = imported.params(name, planner)
            document["orchestrator"]["ros__parameters"]["stop_at_collision"] = False  # every frame timed
            params[planner] = parse_params(document, name)
            stack = Stack(scenario, core_configs(params[planner]))  # built once: ObP compiles its NLP
            runs = [stack.rollout(errors) for _ in range(times)]
            per[planner] = {s: statistics.median(r.stage_times[s] for r in runs) / frames * 1e3 for s in STAGES}
        idm, obp = per["idm"], per["obp"]
        if unavoidable_collision(scenario, params["idm"].ego.length, params["idm"].ego.width) is not None:
            search = f"{'-':>8s} {'-':>8s}  rejected by import-commonroad: unavoidable"
        else:
            try:
                outcome = run_attack(scenario, params["idm"].with_values(  # the README table's method
                    stop_at_collision=True, **{"search.method": "paper"}), progress=False)
                search = f"{outcome.wall_time_s:8.1f} {len(outcome.log):8d}  "
                search += "collision found" if outcome.best else "no collision found"
            except GroundTruthFails:
                search = f"{'-':>8s} {'-':>8s}  refused: the IDM collides at fault with perfect perception"
        print(f"{name:22s} {scenario.agents.shape[1]:8d} {frames:6d} {sum(idm.values()):8.2f} {idm['tracker']:7.2f} "
              f"{idm['planner']:7.2f} {idm['rule']:6.2f} {sum(obp.values()):12.2f} {obp['planner']:11.2f} {search}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--devkit-python", help="python of a venv with nuscenes-devkit 1.2.0")
    parser.add_argument("--sections", type=int, nargs="+", choices=(1, 2, 3, 4), default=(1, 2, 3, 4),
                        help="which sections to run (default: all)")
    parser.add_argument("--scenarios", nargs="+", choices=SCENARIOS, help="section 3's scenarios")
    parser.add_argument("--objectives", nargs="+", choices=OBJECTIVES, help="section 3's objectives")
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=("guided", "paper"),
                        help="section 3's search methods (default: both)")
    args = parser.parse_args()
    if 1 in args.sections:
        bench_rollouts(repeats=5 if args.quick else 20, obp_repeats=1 if args.quick else 3)
    if 2 in args.sections:
        bench_nds(min_seconds=1.0 if args.quick else 3.0, devkit=args.devkit_python)
    if 3 in args.sections:
        scenarios = tuple(args.scenarios or (IDM_SCENARIOS if args.quick else SCENARIOS))
        objectives = tuple(args.objectives or (("nds_t",) if args.quick else OBJECTIVES))
        bench_searches(scenarios, objectives, tuple(args.methods))
    if 4 in args.sections:
        bench_recordings(repeats=3 if args.quick else 5, every=3 if args.quick else 1)


if __name__ == "__main__":
    main()
