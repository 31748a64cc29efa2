"""The graph backend: every rollout driven through the node graph, the nodes separate OS processes.

`GraphRollouts(scenario, params, bag_path)` starts scenario_player, error_injector, tracker,
planner and rule_monitor as child processes speaking Cyclone DDS on `dds.domain_id` (loopback
only unless `dds.localhost_only` is false), or, with `graph.spawn_nodes: false`, uses nodes that
already run (launch/attack.launch.py, an external planner). `rollout(errors)` then returns the
same RolloutResult the embedded `Stack.rollout` returns, so `run_attack` uses it unchanged:

- a rollout is published on /attack/errors (latched) with a fresh rollout id; the injector
  acknowledges it to the player, which runs it in lockstep and reports /attack/done;
- the ego trajectory is read from /ego/odometry, the per-agent signed distances from
  /rules/diagnostics, the verdict (ok or inconclusive, and why) from /attack/done; recorded
  rollouts also keep /tracking/objects and /planning/trajectory.

Readiness: every node we started must have announced itself on the latched /attack/nodes, and
the /attack/errors writer must match a reader (writer-side discovery; builtin-topic readers are
never used, they crash cyclonedds 11.0.1). Then a ground-truth warm-up rollout must complete: it
exercises every edge of the lockstep, so no first message of a real rollout can be lost to
discovery between two nodes. A warm-up that stalls is re-sent under a new id (the player drops
the stalled one) until `STARTUP_TIMEOUT`.

Faults: a child process that exits, a rollout the player reports as timed out, or a graph silent
for longer than `graph.timeout` + `GRACE` makes that rollout inconclusive with one error log line
saying which, and the children are restarted (fresh processes hold no state or stale answers)
before the next rollout. Everything is shut down on exit (SIGTERM, then SIGKILL after
`STOP_TIMEOUT`), and children exit by themselves if this process dies.
"""

import json
import logging
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from advperc_ros.attack import EXTERNAL, AttackedPlanner
from advperc_ros.core.errors import PerceptionErrors
from advperc_ros.core.rollout import RolloutResult
from advperc_ros.core.scenario import Scenario
from advperc_ros.params import PLANNER_PARAMS, AttackParams
from advperc_ros.ros import cdr
from advperc_ros.ros import messages as msgs
from advperc_ros.ros.lockstep import (INCONCLUSIVE, RolloutDone, RolloutErrors, errors_message, parse_done,
                                      parse_presence, parse_rule_diagnostics, plan_from_cdr)
from advperc_ros.ros.topics import (CONTROL_TYPE, DONE, ERRORS, ODOMETRY, PLAN, PRESENCE, RULE_DIAGNOSTICS, TOPIC_TYPES,
                                    TRACKING)
from advperc_ros.ros.transport import Transport

NODES = ("scenario_player", "error_injector", "tracker", "planner", "rule_monitor")
PLANNER_NODE = "planner"
RECORDED = (TRACKING, PLAN)  # topics only recorded rollouts need
STARTUP_TIMEOUT = 60.0  # s for the children to start, discover each other and pass the warm-up
WARMUP_STALL = 0.5  # s without progress after which a warm-up rollout is first re-sent
GRACE = 5.0  # s beyond graph.timeout before a silent graph is declared dead
STOP_TIMEOUT = 5.0  # s between SIGTERM and SIGKILL on shutdown
SPIN = 0.05  # s per transport spin while waiting; per-frame topics are taken at least this often
SETTLE = 0.001  # s per spin once /attack/done is in but per-frame messages are still due
LOG_TAIL = 5  # lines of a dead child's log quoted in the error

log = logging.getLogger("advperc_ros.graph")


class GraphError(RuntimeError):
    """The graph could not be started or made ready; the text says which node and why."""


class _Fault(Exception):
    """A rollout the graph failed to finish (not the planner's verdict)."""


class GraphRollouts:
    """Rollouts through the node graph; a context manager that owns the node processes it starts.
    `transport` (an rclpy node's `RclpyTransport`) is for `graph.spawn_nodes: false` only: nodes
    we start are reached over a Cyclone participant of our own, recreated with them on a restart."""

    def __init__(self, scenario: Scenario, params: AttackParams, bag_path: Path, transport: Transport | None = None) -> None:
        if transport is not None and params.graph.spawn_nodes:
            raise ValueError("a transport can only be given with graph.spawn_nodes false")
        self.scenario = scenario
        self.params = params
        self._spawn = params.graph.spawn_nodes
        self._timeout = params.graph.timeout
        self._given_transport = transport
        self._transport: Any = None  # the given Transport, or a DdsTransport of ours (which we close)
        self._present: dict[str, int] = {}
        self._agent_ids = scenario.agents.ids[scenario.agents.valid.argmax(axis=0), np.arange(scenario.agents.shape[1])]
        self._slots = {int(agent): j for j, agent in enumerate(self._agent_ids)}
        self._stamps = [int(s) for s in scenario.stamps_ns]
        self._next_rollout = 1
        self._workdir = tempfile.TemporaryDirectory(prefix="advperc-graph-")
        self._params_json = json.dumps({**params.flat(), "bag": str(Path(bag_path).resolve()),
                                        PLANNER_PARAMS: dict(params.planner_params)})
        self.processes: dict[str, subprocess.Popen] = {}
        self._received: dict[str, dict[int, Any]] = {}
        self._recording = False
        self._done: list[RolloutDone] = []
        try:
            self._start()
        except BaseException:
            self.close()
            raise

    # -- lifecycle -------------------------------------------------------------------------------

    def _start(self) -> None:
        deadline = time.monotonic() + STARTUP_TIMEOUT
        if self._spawn:
            self._spawn_children()
        self._connect()
        while self._missing():
            dead = self._dead_child()
            if dead is not None:
                raise GraphError(dead)
            if time.monotonic() > deadline:
                raise GraphError(f"not up within {STARTUP_TIMEOUT:g} s: {', '.join(self._missing())}")
            self._transport.spin_once(SPIN)
        self._warm_up(deadline)

    def _missing(self) -> list[str]:
        """What the graph still lacks: a node we started that has not announced itself with its
        pid on /attack/nodes, or (writer-side discovery) an injector matching /attack/errors."""
        missing = [name for name, process in self.processes.items() if self._present.get(name) != process.pid]
        if self._errors.matched_count() < 1:
            missing.append(f"a subscriber of {ERRORS} (the error_injector)")
        return missing

    def _spawn_children(self) -> None:
        root = str(Path(__file__).resolve().parent.parent)
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p))
        flags = ["--params-json", self._params_json, "--domain-id", str(self.params.dds.domain_id),
                 "--localhost-only", "true" if self.params.dds.localhost_only else "false", "--exit-with-parent"]
        for name in NODES:
            with (Path(self._workdir.name) / f"{name}.log").open("ab") as output:
                self.processes[name] = subprocess.Popen(
                    [sys.executable, "-m", f"advperc_ros.nodes.{name}", *flags],
                    stdin=subprocess.DEVNULL, stdout=output, stderr=subprocess.STDOUT, env=env)

    def _connect(self) -> None:
        if self._given_transport is not None:
            self._transport = self._given_transport
        else:
            from advperc_ros.ros.dds import DdsError, DdsTransport

            try:
                self._transport = DdsTransport(self.params.dds.domain_id, self.params.dds.localhost_only)
            except DdsError as exc:
                raise GraphError(str(exc)) from exc
        self._errors = self._transport.publisher(ERRORS, CONTROL_TYPE, latched=True)
        self._received = {}
        for topic in (ODOMETRY, RULE_DIAGNOSTICS, *(RECORDED if self._recording else ())):
            self._subscribe(topic)
        self._transport.subscriber(DONE, CONTROL_TYPE, callback=lambda msg: self._done.append(parse_done(msg)))
        self._present.clear()
        self._transport.subscriber(PRESENCE, CONTROL_TYPE, latched=True, callback=self._on_presence)

    @property
    def attacked_planner(self) -> AttackedPlanner:
        """Our planner node (started by us, or announced on /attack/nodes: the launch file
        configures it from the same params), else an external node, named where the middleware
        tells who publishes the plans."""
        if self._spawn or PLANNER_NODE in self._present:
            return AttackedPlanner(self.params.planner)
        return AttackedPlanner(EXTERNAL, ", ".join(self._transport.publishers_of(PLAN)))

    def _on_presence(self, msg: Any) -> None:
        name, pid = parse_presence(msg)
        self._present[name] = pid

    def _subscribe(self, topic: str) -> None:
        """Keep what `topic` delivers (raw) by stamp, decoded as the result needs it (`_decode`).
        Per-frame messages are only read once the rollout is done, so they do not wake the spin
        (a wake-up per message would compete for the CPU with the nodes in every frame)."""
        received: dict[int, Any] = {}
        self._received[topic] = received

        def keep(data: bytes) -> None:
            stamp, value = self._decode(topic, data)
            received[stamp] = value

        self._transport.subscriber(topic, TOPIC_TYPES[topic], callback=keep, raw=True, wake=False)

    def _decode(self, topic: str, data: bytes) -> tuple[int | None, Any]:
        """(stamp, value) of a payload: EgoState, (minimum, distance per agent id), the tracks or
        the Trajectory."""
        if topic == ODOMETRY:
            return msgs.ego_from_cdr(data, ODOMETRY)
        if topic == RULE_DIAGNOSTICS:
            stamp, minimum, per_agent = parse_rule_diagnostics(data)
            return stamp, (minimum, per_agent)
        if topic == TRACKING:
            return cdr.decode_objects(data, TRACKING)
        return plan_from_cdr(data, self._stamps[0], PLAN)

    def _start_recording(self) -> None:
        """Subscribe to tracks and plans, which only recorded rollouts need (decoding them every
        frame would slow every rollout), and prove the new subscriptions with a warm-up."""
        self._recording = True
        for topic in RECORDED:
            self._subscribe(topic)
        self._warm_up(time.monotonic() + STARTUP_TIMEOUT)

    def _warm_up(self, deadline: float) -> None:
        """One ground-truth rollout through every edge; re-sent when it stalls, with the stall
        allowed doubling each time (a lost first message costs little, a slow planner still passes)."""
        none = PerceptionErrors.none(*self.scenario.agents.shape)
        stall = WARMUP_STALL
        while True:
            rollout = self._send(none)
            try:
                self._collect(rollout, stall=stall, record=self._recording)
                return
            except _Fault as fault:
                if self._dead_child() is not None or time.monotonic() > deadline:
                    raise GraphError(f"the graph did not complete a warm-up rollout: {fault}") from None
            stall *= 2

    def _stop_children(self, kill: bool) -> None:
        for process in self.processes.values():
            if process.poll() is None:
                process.send_signal(signal.SIGKILL if kill else signal.SIGTERM)
        deadline = time.monotonic() + STOP_TIMEOUT
        for process in self.processes.values():
            try:
                process.wait(max(deadline - time.monotonic(), 0.0))
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        self.processes.clear()

    def _restart(self) -> None:
        """Fresh node processes and a fresh participant (the old latched /attack/errors goes with
        it); nodes we did not start are left as they are."""
        if self._spawn:
            self._stop_children(kill=True)
            self._transport.close()
            self._start()

    def close(self) -> None:
        """Stop the children (SIGTERM, then SIGKILL) and the transport; idempotent."""
        self._stop_children(kill=False)
        if self._transport is not None and self._given_transport is None:
            self._transport.close()
        self._transport = None
        self._workdir.cleanup()

    def __enter__(self) -> "GraphRollouts":
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.close()

    def _dead_child(self) -> str | None:
        """What went wrong if a child process has exited, else None."""
        for name, process in self.processes.items():
            code = process.poll()
            if code is not None:
                return f"the {name} process exited with code {code}{self._log_tail(name)}"
        return None

    def _log_tail(self, name: str) -> str:
        path = Path(self._workdir.name) / f"{name}.log"
        lines = path.read_text(errors="replace").strip().splitlines()[-LOG_TAIL:] if path.exists() else []
        return "; its last log lines: " + " | ".join(lines) if lines else ""

    # -- rollouts --------------------------------------------------------------------------------

    def _send(self, errors: PerceptionErrors) -> int:
        rollout = self._next_rollout
        self._next_rollout += 1
        for received in self._received.values():
            received.clear()
        self._done.clear()
        self._errors.publish(errors_message(RolloutErrors(rollout, errors, self._agent_ids, self.scenario.stamps_ns)))
        return rollout

    def _collect(self, rollout: int, stall: float, record: bool) -> RolloutDone:
        """Spin until the player's /attack/done for `rollout` and every message it implies are in."""
        idle_since = time.monotonic()
        done = None
        while True:
            if self._transport.spin_once(SPIN if done is None else SETTLE):
                idle_since = time.monotonic()
            dead = self._dead_child()
            if dead is not None:
                raise _Fault(dead)
            done = next((d for d in self._done if d.rollout == rollout), None)
            if done is not None and (done.timeout or self._complete(done, record)):
                if done.timeout:
                    raise _Fault(done.reason)
                return done
            if time.monotonic() - idle_since > stall:
                raise _Fault(f"no message from the graph for {stall:g} s (player, injector or rule monitor dead or silent)")

    def _complete(self, done: RolloutDone, record: bool) -> bool:
        """Whether every message the finished rollout implies is in (/attack/done may overtake
        them: they come from other processes)."""
        stamps = self._stamps[: done.frames]
        if not all(s in self._received[topic] for topic in (ODOMETRY, RULE_DIAGNOSTICS) for s in stamps):
            return False
        return not record or (all(s in self._received[TRACKING] for s in stamps[: self._tracked_frames(done)])
                              and all(s in self._received[PLAN] for s in stamps[: self._planned_frames(done)]))

    def _stopped_at_violation(self, done: RolloutDone) -> bool:
        if done.status == INCONCLUSIVE or not self.params.stop_at_collision:
            return False
        minimum, _ = self._received[RULE_DIAGNOSTICS][self._stamps[done.frames - 1]]
        return minimum < 0.0

    def _tracked_frames(self, done: RolloutDone) -> int:
        """Frames whose tracks the embedded rollout records: all but one it stopped at a violation."""
        return done.frames - 1 if self._stopped_at_violation(done) else done.frames

    def _planned_frames(self, done: RolloutDone) -> int:
        """Frames whose plan the embedded rollout records: not the one that made it inconclusive."""
        return self._tracked_frames(done) - (1 if done.status == INCONCLUSIVE else 0)

    def rollout(self, errors: PerceptionErrors, record: bool = False) -> RolloutResult:
        if record and not self._recording:
            self._start_recording()
        rollout = self._send(errors)
        try:
            done = self._collect(rollout, stall=self._timeout + GRACE, record=record)
        except _Fault as fault:
            reason = f"graph failure in rollout {rollout}: {fault}"
            log.error(f"rollout {rollout} inconclusive: {fault}; "
                      + ("restarting the graph nodes" if self._spawn else "going on with the running nodes"))
            result = self._result(self._frames_received(), reason, record=False)
            if record:  # the attack bag is still written, without tracks and plans
                result.tracks, result.plans = [], []
            self._restart()
            return result
        if done.reason:
            log.warning(f"rollout {rollout} {done.status}: {done.reason}")
        return self._result(done.frames, done.reason or None, record, done)

    def _frames_received(self) -> int:
        frames = 0
        while frames < len(self._stamps) and all(self._stamps[frames] in self._received[t] for t in (ODOMETRY, RULE_DIAGNOSTICS)):
            frames += 1
        return frames

    def _result(self, frames: int, inconclusive: str | None, record: bool, done: RolloutDone | None = None) -> RolloutResult:
        stamps = self._stamps[:frames]
        ego = np.zeros((frames, 4))
        distances = np.full((frames, len(self._agent_ids)), np.inf)
        for k, stamp in enumerate(stamps):
            state = self._received[ODOMETRY][stamp]
            ego[k] = (state.x, state.y, state.yaw, state.v)
            _, per_agent = self._received[RULE_DIAGNOSTICS][stamp]
            for agent, distance in per_agent.items():
                distances[k, self._slots[agent]] = distance
        result = RolloutResult(ego=ego, distances=distances, inconclusive=inconclusive)
        if record and done is not None:
            result.tracks = [self._received[TRACKING][s] for s in stamps[: self._tracked_frames(done)]]
            result.plans = [self._received[PLAN][s] for s in stamps[: self._planned_frames(done)]]
        return result

