"""The extended error space against the paper's, at equal rollouts (docs/errors.md).

Per scenario and seed, the guided search runs with the paper's kinds first (`errors.kinds: paper`);
then with the kinds given (default `all`) and exactly the rollouts the first used. Prints per run the
metric, NDS and NDS-t of the best attack, the colliding rollouts, and the kinds the attack uses; then
per scenario the median over the seeds of both.

    python benchmarks/error_kinds_bench.py --scenarios obp_right_turn --seeds 0 1 2
    python benchmarks/error_kinds_bench.py --kinds ghost,latency --objective nds
"""

import argparse
import json
import statistics

from search_bench import SCENARIOS, attack


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenarios", nargs="+", default=SCENARIOS, choices=SCENARIOS)
    parser.add_argument("--seeds", type=int, nargs="+", default=(0, 1, 2, 3, 4))
    parser.add_argument("--objective", default="nds_t", choices=("nds", "nds_t", "pem_ll"))
    parser.add_argument("--kinds", default="all", help="errors.kinds of the second search (default: all)")
    args = parser.parse_args()
    print("| scenario | seed | kinds | rollouts | collisions | metric | NDS | NDS-t | kinds used |")
    print("|---|---|---|---|---|---|---|---|---|")
    medians = {}
    for name in args.scenarios:
        runs: dict[str, list[float]] = {"paper": [], args.kinds: []}
        for seed in args.seeds:
            paper = attack(name, args.objective, seed, "guided")
            extended = attack(name, args.objective, seed, "guided", budget=paper["rollouts"], errors=args.kinds)
            for kinds, run in (("paper", paper), (args.kinds, extended)):
                runs[kinds].append(run["metric"])
                print(f"| {name} | {seed} | {kinds} | {run['rollouts']} | {run['collisions']} | {run['metric']:.4f} | "
                      f"{run['nds']:.4f} | {run['nds_t']:.4f} | {', '.join(run['kinds']) or '-'} |", flush=True)
        medians[name] = {kinds: statistics.median(values) for kinds, values in runs.items()}
    print(json.dumps({"objective": args.objective, "median_metric": medians}, indent=1))


if __name__ == "__main__":
    main()
