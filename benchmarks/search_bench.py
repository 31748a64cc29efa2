"""The paper's search against the guided search at equal rollout budgets (README "Search").

Per scenario and seed, the paper's method runs first; the guided method then gets exactly the
rollouts the paper's used on that scenario and seed. Prints per scenario the median and worst
metric over the seeds (with NDS, NDS-t and PEM LL of the attacks), the rollouts each method needed
to reach the paper's Table 1 figure, and optionally the wall time of a guided search on 1 and 2
workers at equal budget, measured alternately in one run. Writes the best metric against rollouts
(median over seeds) to docs/search_methods.png.

    python benchmarks/search_bench.py --scenarios idm_lane_following --seeds 0 1 2 3 4
    python benchmarks/search_bench.py --workers-scenario obp_left_turn --workers-repeats 2
"""

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))  # measure this checkout, not whichever advperc_ros is installed

from advperc_ros.application import run_attack  # noqa: E402
from advperc_ros.params import load_params  # noqa: E402
from advperc_ros.ros.bag import read_scenario  # noqa: E402

SCENARIOS = ("idm_lane_following", "idm_overtake_follow", "obp_overtake", "obp_left_turn", "obp_right_turn")
PAPER = {  # Table 1 of the paper
    "nds_t": {"idm_lane_following": 0.88, "idm_overtake_follow": 0.98, "obp_overtake": 0.97, "obp_left_turn": 0.99,
              "obp_right_turn": 0.98},
    "nds": {"idm_lane_following": 0.81, "idm_overtake_follow": 0.94, "obp_overtake": 0.96, "obp_left_turn": 0.98,
            "obp_right_turn": 0.97},
}


def attack(name: str, objective: str, seed: int, method: str, budget: int = 0, workers: int = 1,
           errors: str = "paper") -> dict:
    """One search; its best attack's scores, its rollouts and the best metric after each rollout."""
    params = load_params(REPO / "config" / f"{name}.yaml").with_values(
        objective=objective, seed=seed, **{"search.method": method, "search.budget": budget, "workers": workers,
                                           "errors.kinds": errors})
    started = time.perf_counter()
    outcome = run_attack(read_scenario(REPO / "bags" / name), params, progress=False)
    wall = time.perf_counter() - started
    best = outcome.best
    curve = [row.best_metric for row in outcome.log]
    kinds = best.errors.used_kinds(best.rollout.num_frames) if best else ()
    return {"scenario": name, "objective": objective, "seed": seed, "method": method, "rollouts": len(outcome.log),
            "kinds": kinds, "collisions": sum(row.collided for row in outcome.log),
            "metric": best.metric if best else float("nan"), "nds": best.scores.nds if best else float("nan"),
            "nds_t": best.scores.nds_t if best else float("nan"), "pem_ll": best.scores.pem_ll if best else float("nan"),
            "curve": curve, "wall_s": wall}


def reached(curve: list[float], figure: float | None) -> int | None:
    """The rollout (1-based) at which the best metric first reached the paper's figure."""
    if figure is None:
        return None
    hits = [i + 1 for i, value in enumerate(curve) if value >= figure]
    return hits[0] if hits else None


def compare(scenarios, objectives, seeds, out: Path) -> None:
    """Appends to `out` the searches it does not hold yet (an ObP search takes minutes)."""
    done = {(r["scenario"], r["objective"], r["seed"], r["method"]): r for r in load(out)}
    for name in scenarios:
        for objective in objectives:
            for seed in seeds:
                paper = done.get((name, objective, seed, "paper"))
                for method in ("paper", "guided"):
                    if (name, objective, seed, method) in done:
                        continue
                    row = attack(name, objective, seed, method, budget=paper["rollouts"] if paper else 0)
                    row["reached"] = reached(row["curve"], PAPER.get(objective, {}).get(name))
                    paper = paper or row
                    print(json.dumps({k: v for k, v in row.items() if k != "curve"}), flush=True)
                    with out.open("a") as handle:
                        handle.write(json.dumps(row) + "\n")


def load(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.exists() else []


def table(rows: list[dict]) -> None:
    print(f"\n{'scenario':20s} {'objective':7s} {'method':6s} {'seeds':>5s} {'median':>7s} {'worst':>7s} "
          f"{'NDS med':>7s} {'NDS-t med':>9s} {'PEM LL med':>10s} {'rollouts':>8s}  reached paper figure at")
    keys = sorted({(r["scenario"], r["objective"], r["method"]) for r in rows},
                  key=lambda k: (SCENARIOS.index(k[0]), k[1], k[2] != "paper"))
    for name, objective, method in keys:
        group = [r for r in rows if (r["scenario"], r["objective"], r["method"]) == (name, objective, method)]
        group.sort(key=lambda r: r["seed"])
        metric = [r["metric"] for r in group]
        worst = min(metric)
        print(f"{name:20s} {objective:7s} {method:6s} {len(group):5d} {statistics.median(metric):7.4f} {worst:7.4f} "
              f"{statistics.median(r['nds'] for r in group):7.4f} {statistics.median(r['nds_t'] for r in group):9.4f} "
              f"{statistics.median(r['pem_ll'] for r in group):10.3f} "
              f"{'/'.join(str(r['rollouts']) for r in group):>8s}  "
              f"{'/'.join(str(r['reached']) if r['reached'] else '-' for r in group)}")


def workers_ratio(name: str, objective: str, budget: int, repeats: int) -> None:
    """Guided search on 1 and 2 workers, alternately, at one budget; same attack required."""
    times = {1: [], 2: []}
    for _ in range(repeats):
        results = {}
        for workers in (1, 2):
            results[workers] = attack(name, objective, 0, "guided", budget=budget, workers=workers)
            times[workers].append(results[workers]["wall_s"])
        assert np.array_equal(results[1]["curve"], results[2]["curve"], equal_nan=True), "the attack depends on the workers"
    one, two = statistics.median(times[1]), statistics.median(times[2])
    print(f"\n{name} {objective} guided, budget {budget}: 1 worker {times[1]} s, 2 workers {times[2]} s; "
          f"median ratio {two / one:.2f}")


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = sorted({(r["scenario"], r["objective"]) for r in rows}, key=lambda k: (SCENARIOS.index(k[0]), k[1]))
    fig, axes = plt.subplots(1, len(groups), figsize=(3.2 * len(groups), 3.0), squeeze=False)
    for ax, (name, objective) in zip(axes[0], groups):
        for method, colour in (("paper", "tab:blue"), ("guided", "tab:red")):
            curves = [r["curve"] for r in rows if (r["scenario"], r["objective"], r["method"]) == (name, objective, method)]
            if not curves:
                continue
            length = max(len(c) for c in curves)
            padded = np.array([c + [c[-1]] * (length - len(c)) for c in curves], dtype=float)
            ax.plot(np.arange(1, length + 1), np.nanmedian(padded, axis=0), color=colour, label=method)
        figure = PAPER.get(objective, {}).get(name)
        if figure is not None:
            ax.axhline(figure, color="grey", linestyle=":", label="paper Table 1")
        seeds = len({r["seed"] for r in rows if (r["scenario"], r["objective"]) == (name, objective)})
        ax.set_title(f"{name}\n{objective}, {seeds} seeds", fontsize=8)
        ax.set_xlabel("rollouts", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0][0].set_ylabel("best metric (median over seeds)", fontsize=8)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenarios", nargs="*", default=list(SCENARIOS), choices=SCENARIOS)
    parser.add_argument("--objectives", nargs="+", default=["nds_t"], choices=("nds", "nds_t", "pem_ll"))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
    parser.add_argument("--results", type=Path, default=Path("search_bench.jsonl"),
                        help="one JSON line per search, appended; searches already there are not run again")
    parser.add_argument("--table-only", action="store_true", help="print the tables and plot of --results only")
    parser.add_argument("--plot", type=Path, default=REPO / "docs" / "search_methods.png")
    parser.add_argument("--workers-scenario", choices=SCENARIOS)
    parser.add_argument("--workers-budget", type=int, default=40)
    parser.add_argument("--workers-repeats", type=int, default=2)
    args = parser.parse_args()
    if not args.table_only and args.scenarios:
        compare(args.scenarios, args.objectives, args.seeds, args.results)
    rows = load(args.results)
    if rows:
        table(rows)
        curves = [r for r in rows if r["objective"] == "nds_t"]
        if curves:  # the plot is of nds_t searches only
            plot(curves, args.plot)
    if args.workers_scenario:
        workers_ratio(args.workers_scenario, "nds_t", args.workers_budget, args.workers_repeats)


if __name__ == "__main__":
    main()
