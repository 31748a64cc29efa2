"""Why a planner node costs more than the same planner embedded: its `plan()` calls timed in both.

    python benchmarks/planner_process_cost.py [--rollouts 4] [--domain-id 176] [SCENARIO]

On obp_overtake (by default) the graph's ratio to the embedded rollout stays above its goal because
the planner node spends more CPU than the embedded rollout's planner on the same frames. This
benchmark splits that excess, in one run:

1. **In the graph.** The ground-truth rollout `--rollouts` times, embedded and over the bare-Cyclone
   graph in turn. Each `plan()` call is timed by its own thread's CPU clock, in this process and in
   the planner node (whose interpreter loads `_plan_timer/sitecustomize.py`, which wraps the
   planner's `plan` and reports its tallies on SIGUSR1); the node's whole CPU comes from /proc.
   Printed: `plan()` in each process, the node's CPU outside `plan()` (decoding, encoding,
   middleware) against the embedded rollout's outside it (tracking, injection, rule), and the
   player node's CPU.
2. **Replayed.** The embedded rollout's own `plan()` inputs replayed in this process, `--rollouts`
   times per variant in turn: back to back; on the inputs the node gets (tracks and odometry
   encoded to CDR and decoded again); with a 1 ms sleep before each call (the node sleeps while the
   player works); in ping-pong with another process that works 1 ms a frame (the node is woken by
   another process); and with a Cyclone participant's threads in the process.

Each variant's ratio to back-to-back `plan()` says how much of the node's excess it explains.
All DDS traffic stays on loopback. No timings are asserted anywhere: the machine is shared.
"""

import argparse
import importlib.util
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
TIMER = Path(__file__).resolve().parent / "_plan_timer"
sys.path.insert(0, str(REPO))


def _load_timer():
    """The wrapper the nodes load as their sitecustomize, loaded here under a name of its own (this
    interpreter may have imported another sitecustomize at start)."""
    spec = importlib.util.spec_from_file_location("advperc_plan_timer", TIMER / "sitecustomize.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


plan_timer = _load_timer()  # this process's plan() tallies

from graph_bench import bundled_on_graph  # noqa: E402
from hop_cost import load_average  # noqa: E402

from advperc_ros.backends.embedded import Stack  # noqa: E402
from advperc_ros.backends.graph.rollouts import GraphRollouts  # noqa: E402
from advperc_ros.configs import core_configs  # noqa: E402
from advperc_ros.core.perception_errors import PerceptionErrors  # noqa: E402
from advperc_ros.heap import keep_freed_heap  # noqa: E402
from advperc_ros.params import load_params  # noqa: E402
from advperc_ros.ros import messages as msgs  # noqa: E402
from advperc_ros.ros.bag import read_scenario  # noqa: E402
from advperc_ros.ros.interfaces.registry import load_profile  # noqa: E402

FRAME_WORK_S = 0.001  # what the other process works per frame in the ping-pong variant (the player's turn)


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def node_report(pid: int, folder: Path) -> dict:
    """What the timer wrapper of node process `pid` kept (its SIGUSR1 report, written into `folder`):
    the tally of its plan() calls so far, and the plan() calls and marks since its last report."""
    path = folder / f"{pid}.json"
    path.unlink(missing_ok=True)
    os.kill(pid, signal.SIGUSR1)
    deadline = time.monotonic() + 10
    while not path.exists() and time.monotonic() < deadline:
        time.sleep(0.01)
    return json.loads(path.read_text())


def _node_plan_seconds(pid: int, folder: Path) -> float:
    """The thread CPU seconds of the planner node's plan() calls so far."""
    return float(node_report(pid, folder)["seconds"])


def in_the_graph(name: str, rollouts: int, domain_id: int) -> dict[str, float]:
    bag, scenario, params, stack = bundled_on_graph(name, domain_id)
    errors = PerceptionErrors.none(*scenario.agents.shape)
    stack.rollout(errors)  # warm
    out = dict.fromkeys(("embedded", "embedded_plan", "node", "node_plan", "player"), 0.0)
    with tempfile.TemporaryDirectory(prefix="advperc-plan-timer-") as folder:
        os.environ["ADVPERC_PLAN_TIMER"] = folder  # the node processes inherit it, and the wrapper's path
        os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(TIMER), os.environ.get("PYTHONPATH")) if p)
        with GraphRollouts(scenario, core_configs(params), bag) as graph:
            planner, player = (graph.processes.running[node].pid for node in ("planner", "scenario_player"))
            for _ in range(rollouts):
                seconds = plan_timer.tally()[1]
                before = time.process_time()
                stack.rollout(errors)
                out["embedded"] += time.process_time() - before
                out["embedded_plan"] += plan_timer.tally()[1] - seconds
                node_seconds = _node_plan_seconds(planner, Path(folder))
                node_before, player_before = _cpu_seconds(planner), _cpu_seconds(player)
                graph.rollout(errors)
                out["node"] += _cpu_seconds(planner) - node_before
                out["player"] += _cpu_seconds(player) - player_before
                out["node_plan"] += _node_plan_seconds(planner, Path(folder)) - node_seconds
        out["frames"] = rollouts * scenario.num_frames
    return out


def _inputs(name: str) -> tuple[Stack, list[tuple]]:
    """The embedded rollout's `plan()` inputs (t, ego, tracks), frame by frame, and its stack."""
    scenario = read_scenario(REPO / "bags" / name)
    stack = Stack(scenario, core_configs(load_params(REPO / "config" / f"{name}.yaml")))
    seen: list[tuple] = []
    planner = stack.planner
    plan = planner.plan
    planner.plan = lambda t, ego, tracks: (seen.append((t, ego, tracks)), plan(t, ego, tracks))[1]
    stack.rollout(PerceptionErrors.none(*scenario.agents.shape))
    planner.plan = plan
    return stack, seen


def _through_cdr(seen: list[tuple], first_stamp_ns: int) -> list[tuple]:
    """The inputs as the planner node gets them: tracks and odometry encoded and decoded again."""
    tracks_layer = load_profile("advperc").tracks
    out = []
    for t, ego, tracks in seen:
        stamp = first_stamp_ns + round(t * 1e9)
        _, decoded = tracks_layer.decode(tracks_layer.encode(tracks, stamp, "tracking"), "tracks")
        _, ego_back = msgs.ego_from_cdr(msgs.ego_to_cdr(ego, stamp), "odometry")
        out.append((t, ego_back, decoded))
    return out


def _partner(read_fd: int, write_fd: int) -> None:
    """The other process of the ping-pong: on each byte, work FRAME_WORK_S, then answer."""
    while os.read(read_fd, 1) == b"x":
        end = time.perf_counter() + FRAME_WORK_S
        while time.perf_counter() < end:
            pass
        os.write(write_fd, b"x")


def replayed(name: str, rollouts: int, domain_id: int) -> dict[str, float]:
    stack, seen = _inputs(name)
    planner = stack.planner
    via_cdr = _through_cdr(seen, int(stack.scenario.stamps_ns[0]))
    to_partner, from_partner = os.pipe(), os.pipe()
    partner = subprocess.Popen([sys.executable, "-c", f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); "
                                f"import planner_process_cost as b; b._partner({to_partner[0]}, {from_partner[1]})"],
                               pass_fds=(to_partner[0], from_partner[1]))

    def ping() -> None:
        os.write(to_partner[1], b"x")
        os.read(from_partner[0], 1)

    def run(inputs: list[tuple], before_each: Callable[[], None] | None) -> float:
        planner.reset()
        used = 0.0
        for t, ego, tracks in inputs:
            if before_each is not None:
                before_each()
            started = time.thread_time()
            planner.plan(t, ego, tracks)
            used += time.thread_time() - started
        return used

    variants: dict[str, tuple[list[tuple], Callable[[], None] | None]] = {
        "back to back": (seen, None), "the node's inputs (through CDR)": (via_cdr, None),
        "1 ms sleep before each call": (seen, lambda: time.sleep(0.001)),
        "ping-pong with another process": (seen, ping)}
    times: dict[str, list[float]] = {label: [] for label in [*variants, "with a Cyclone participant"]}
    try:
        for _ in range(rollouts):
            for label, (inputs, before_each) in variants.items():
                times[label].append(run(inputs, before_each))
        from advperc_ros.ros.dds import DdsTransport
        participant = DdsTransport(domain_id, localhost_only=True)  # its threads live with the planner's from here
        for _ in range(rollouts):
            times["with a Cyclone participant"].append(run(seen, None))
        participant.close()
    finally:
        os.write(to_partner[1], b"q")
        partner.wait(timeout=10)
    return {label: statistics.median(values) for label, values in times.items()}


def back_to_back(name: str, rollouts: int, keep_heap: bool) -> float:
    """The median thread CPU of the embedded rollout's plan() calls replayed back to back in this
    process, with `advperc_ros.heap.keep_freed_heap` or glibc's own malloc thresholds: what
    `fresh_processes` runs in each child."""
    if keep_heap:
        keep_freed_heap()
    stack, seen = _inputs(name)
    times = []
    for _ in range(rollouts):
        stack.planner.reset()
        started = time.thread_time()
        for t, ego, tracks in seen:
            stack.planner.plan(t, ego, tracks)
        times.append(time.thread_time() - started)
    return statistics.median(times)


def fresh_processes(name: str, rollouts: int, processes: int) -> dict[bool, list[float]]:
    """`back_to_back` in new interpreters, `processes` with glibc's malloc thresholds and as many with
    `keep_freed_heap`, in turn: what the same calls cost a process that starts afresh, as a node does."""
    out: dict[bool, list[float]] = {False: [], True: []}
    for _ in range(processes):
        for keep_heap in (False, True):
            code = (f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); import planner_process_cost as b; "
                    f"print(b.back_to_back({name!r}, {rollouts}, {keep_heap}))")
            out[keep_heap].append(float(subprocess.run(
                [sys.executable, "-c", code], check=True, capture_output=True, text=True,
                env=dict(os.environ, PYTHONPATH=str(REPO))).stdout.split()[-1]))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scenario", nargs="?", default="obp_overtake")
    parser.add_argument("--rollouts", type=int, default=4)
    parser.add_argument("--domain-id", type=int, default=176)
    parser.add_argument("--processes", type=int, default=4, help="fresh processes replaying back to back")
    args = parser.parse_args()
    keep_freed_heap()  # as `advperc attack` and the nodes do
    print(f"== {args.scenario}: the planner in the graph and embedded, {args.rollouts} ground-truth rollouts each, "
          f"in turn; {load_average()} ==")
    graph = in_the_graph(args.scenario, args.rollouts, args.domain_id)
    per_frame = 1e3 / graph["frames"]
    print(f"plan() CPU: embedded {graph['embedded_plan']:.3f} s, planner node {graph['node_plan']:.3f} s: "
          f"{graph['node_plan'] / graph['embedded_plan']:.3f}x")
    print(f"CPU outside plan(): the node {(graph['node'] - graph['node_plan']) * per_frame:.2f} ms a frame (decoding, "
          f"encoding, middleware), the embedded rollout {(graph['embedded'] - graph['embedded_plan']) * per_frame:.2f} ms "
          f"(tracking, injection, rule); the player node {graph['player'] * per_frame:.2f} ms")
    print(f"the whole planner node / the whole embedded rollout: {graph['node'] / graph['embedded']:.3f}x")
    print(f"== the embedded rollout's plan() inputs replayed in this process (median of {args.rollouts}) ==")
    replay = replayed(args.scenario, args.rollouts, args.domain_id + 1)
    base = replay["back to back"]
    for label, seconds in replay.items():
        print(f"{label:34s} {seconds:7.3f} s  {seconds / base:6.3f}x")
    fresh = fresh_processes(args.scenario, args.rollouts, args.processes)
    for keep_heap, label in ((False, "glibc's malloc thresholds"), (True, "keep_freed_heap()")):
        print(f"back to back in fresh processes, {label}: "
              + ", ".join(f"{seconds:.3f} s ({seconds / base:.3f}x)" for seconds in fresh[keep_heap]))


if __name__ == "__main__":
    main()
