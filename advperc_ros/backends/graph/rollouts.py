"""The graph backend the search uses: every rollout through the node graph, the nodes separate processes.

`GraphRollouts(scenario, configs, bag_path)` starts scenario_player, error_injector, tracker,
planner and rule_monitor as child processes speaking Cyclone DDS on `dds.domain_id` (loopback
only unless `dds.localhost_only` is false), or, with `graph.spawn_nodes: false`, uses nodes that
already run (launch/attack.launch.py, an external planner). `rollout(errors)` then returns the
same RolloutResult the embedded `Stack.rollout` returns, so `run_attack` uses it unchanged:

- a rollout is published on /attack/errors (latched) with a fresh rollout id; the injector
  acknowledges it to the player, which runs it in lockstep and reports /attack/done;
- the ego trajectory is read from /ego/odometry, the per-agent signed distances from
  /rules/diagnostics, the verdict (ok or inconclusive, and why) from /attack/done; recorded
  rollouts also keep /tracking/objects and /planning/trajectory;
- the first conclusive rollout on perfect perception (the ground truth's, which every search runs
  first, or which a resumed attack answers from its checkpoint: `observe`) is published on the
  latched /attack/reference, for the rule monitor's rules that compare the drive with it.

Readiness: every node we started must have announced itself on the latched /attack/nodes, and
the /attack/errors writer must match a reader (writer-side discovery; builtin-topic readers are
never used, they crash cyclonedds 11.0.1). Then a ground-truth warm-up rollout must complete: it
exercises every edge of the lockstep, so no first message of a real rollout can be lost to
discovery between two nodes. A warm-up that stalls is re-sent under a new id (the player drops
the stalled one) until `STARTUP_TIMEOUT`.

Faults: a node gone for good (a child process that exited, or, over rclpy, a team's node that left
the ROS graph: `left_the_graph`) stops the search at once with `NodeGone`, naming it and how it
went, the checkpoint kept: every rollout after would wait out its timeout and find nothing. A
rollout the player reports as timed out, or a graph silent for longer than `graph.timeout` +
`GRACE`, makes that rollout inconclusive with one error log line saying which, and the children are
restarted (fresh processes hold no state or stale answers) before the next rollout. Everything is
shut down on exit (SIGTERM, then SIGKILL after `STOP_TIMEOUT`), and children exit by themselves if
this process dies.
"""

import json
import logging
import os
import secrets
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from advperc_ros.backends.base import EXTERNAL, AttackedPlanner
from advperc_ros.backends.graph.assembly import assemble, frames_in, kept_frames
from advperc_ros.backends.graph.client import SPIN, LockstepClient
from advperc_ros.backends.graph.processes import NodeProcesses
from advperc_ros.configs import CoreConfigs
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.rollout import RolloutResult, judge
from advperc_ros.core.scenario import Scenario
from advperc_ros.exceptions import GraphError, NodeGone, RolloutFault
from advperc_ros.nodes.graph_nodes import SPECS, node_parameters
from advperc_ros.ros.interfaces.base import Profile
from advperc_ros.ros.lockstep import ReferenceDrive, Status, reference_message
from advperc_ros.ros.topics import ERRORS, PRESENCE
from advperc_ros.ros.transport import Transport

PLANNER_NODE = "planner"
TRACKER_NODE = "tracker"
STARTUP_TIMEOUT = 60.0  # s for the children to start, discover each other and pass the warm-up
WARMUP_STALL = 0.5  # s without progress after which a warm-up rollout is first re-sent
GRACE = 5.0  # s beyond graph.timeout before a silent graph is declared dead
LOOK_EVERY = 0.5  # s between looks at the ROS graph for a node that left it, while a rollout waits
RECORD_CHECK = "the ground-truth rollout that proves the tracks and plans subscriptions before the best attack is recorded"

log = logging.getLogger("advperc_ros.backends.graph")


@dataclass(frozen=True)
class Watched:
    """What of a graph of running nodes (`graph.spawn_nodes: false`) was seen once it was up: the
    nodes announced on /attack/nodes that the ROS graph showed under that name, and the nodes
    publishing each topic a rollout needs from a team's node. Only what was seen can be missed: a
    node announced under a name that is not its ROS name is never taken for gone."""

    nodes: frozenset[str] = frozenset()
    publishers: dict[str, tuple[str, ...]] = field(default_factory=dict)


class GraphRollouts:
    """Rollouts through the node graph; a context manager that owns the node processes it starts.
    `transport` (an rclpy node's `RclpyTransport`) is for `graph.spawn_nodes: false` only: nodes
    we start are reached over a Cyclone participant of our own, recreated with them on a restart."""

    def __init__(self, scenario: Scenario, configs: CoreConfigs, bag_path: Path,
                 transport: Transport | None = None) -> None:
        self.scenario = scenario
        self.planner = configs.planner.name
        self.execution = execution = configs.execution
        self.stop_at_collision = configs.rollout.stop_at_collision
        self.profile = configs.profile
        self._given_transport = transport
        agents = scenario.agents
        self._agent_ids = agents.ids[agents.valid.argmax(axis=0), np.arange(agents.shape[1])]
        self._slots = {int(agent): j for j, agent in enumerate(self._agent_ids)}
        self._stamps = [int(s) for s in scenario.stamps_ns]
        params_json = json.dumps({**execution.node_values, "bag": str(Path(bag_path).resolve())})
        # nodes we start under an rclpy orchestrator are rclpy nodes too, visible to the ROS tools
        ros_nodes = ({spec.name: node_parameters(spec, execution.node_values, Path(bag_path)) for spec in SPECS}
                     if transport is not None and execution.spawn_nodes else None)
        # a bare graph we start talks in a DDS partition of its own: any number of them share a domain
        # (rclpy nodes cannot: another graph on their domain is refused at start, see `_refuse_others`)
        self._partition = (f"advperc-{os.getpid()}-{secrets.token_hex(4)}"
                           if execution.spawn_nodes and ros_nodes is None else "")
        self.processes = NodeProcesses(params_json, execution.domain_id, execution.localhost_only, self._partition,
                                       ros_nodes)
        self._config = configs.rollout
        self._client: LockstepClient | None = None
        self._own_transport: Any = None  # a DdsTransport we made (not the given one), closed with the graph
        self._recording = False
        self._reference: ReferenceDrive | None = None  # the ground truth's rollout, once seen
        self._watched = Watched()  # the running nodes' graph once it was up (`graph.spawn_nodes: false`)
        try:
            self._start()
        except BaseException:
            self.close()
            raise
        log.info(self._attacking())

    def _attacking(self) -> str:
        """What the rollouts go through, said once the graph is up: a team's planner (or tracker) is
        not the params' own, and the params' planner and planner_params then do not apply."""
        attacked = self.attacked_planner
        if attacked.node is None:
            said = f"attacking our planner node ({self.planner})"
        else:
            version = f" version {attacked.version}" if attacked.version is not None else ""
            said = (f"attacking the external planner {attacked.node or '(bare DDS names no nodes)'}{version} on "
                    f"{self.profile.plan.topic}; the params' planner '{self.planner}' and its planner_params "
                    "do not apply to it")
        if attacked.tracker_node is not None:
            said += f"; tracks from the external tracker {attacked.tracker_node or '(unnamed)'}"
        return said

    # -- lifecycle -------------------------------------------------------------------------------

    def _start(self, warm_up: str = "a warm-up rollout") -> None:
        """Start (or restart) the graph and prove it with `warm_up`, the ground-truth rollout a failure names."""
        deadline = time.monotonic() + STARTUP_TIMEOUT
        if self.execution.spawn_nodes:
            self.processes.start()
        if self._client is None:  # a given transport keeps its client (and its rollout ids) across restarts
            self._client = LockstepClient(self._transport(), self._agent_ids, self.scenario.stamps_ns,
                                          self.stop_at_collision, self.profile)
            if self._recording:
                self.client.record_too()
            if self._reference is not None:  # a fresh participant: latched again for fresh nodes
                self.client.reference.publish(reference_message(self._reference))
        while self._missing():
            dead = self.processes.dead()
            if dead is not None:
                raise GraphError(dead)
            self._refuse_others()
            if time.monotonic() > deadline:
                raise GraphError(f"not up within {STARTUP_TIMEOUT:g} s: {', '.join(self._missing())}")
            self.client.transport.spin_once(SPIN)
        self._warm_up(deadline, warm_up)
        self._refuse_others()  # also a graph that came up beside ours while it started
        if not self.execution.spawn_nodes:
            self._watched = watch(self.client.transport, self.client.present, self.profile)

    @property
    def client(self) -> LockstepClient:
        """The lockstep client of the running graph (there is none before `_start` or after `close`)."""
        if self._client is None:
            raise GraphError("the graph is closed")
        return self._client

    def _transport(self) -> Transport:
        """The given transport, or a Cyclone participant of our own (`_own_transport`, closed with the graph)."""
        if self._given_transport is not None:
            return self._given_transport
        from advperc_ros.exceptions import DdsError
        from advperc_ros.ros.dds import DdsTransport

        try:
            self._own_transport = DdsTransport(self.execution.domain_id, self.execution.localhost_only,
                                               self._partition)
        except DdsError as exc:
            raise GraphError(str(exc)) from exc
        return self._own_transport

    def _close_own_transport(self) -> None:
        if self._own_transport is not None:
            self._own_transport.close()
            self._own_transport = None

    def _missing(self) -> list[str]:
        """What the graph still lacks: a node we started that has not announced itself with its
        pid on /attack/nodes, or (writer-side discovery) an injector matching /attack/errors."""
        present = self.client.present
        missing = [name for name, process in self.processes.running.items() if present.get(name) != process.pid]
        if self.client.errors.matched_count() < 1:
            missing.append(f"a subscriber of {ERRORS} (the error_injector)")
        return missing

    def _refuse_others(self) -> None:
        """Refuse to run beside another graph on this graph's domain and partition, seen as one of
        our node names announced with a process id that is not ours (we started the nodes), or with
        two ids: the two graphs' messages would mix, and most rollouts end superseded."""
        ours = {process.pid for process in self.processes.running.values()}
        found = []
        for name, pids in sorted(self.client.announced.items()):
            strangers = sorted(pids - ours) if self.execution.spawn_nodes else sorted(pids)[1:]
            found += [f"{name} pid {pid}" for pid in strangers]
        if found:
            domain = "ROS_DOMAIN_ID" if self._given_transport is not None else "dds.domain_id"
            raise GraphError(f"another graph is running on this graph's DDS domain ({', '.join(found)}): its messages "
                             f"would mix with this attack's; stop it or give this attack another {domain}")

    @property
    def attacked_planner(self) -> AttackedPlanner:
        """Our planner node (started by us, or announced on /attack/nodes: the launch file
        configures it from the same params), else an external node, named where the middleware
        tells who publishes the plans; the same for the tracker whose tracks it read."""
        def publishers(topic: str) -> str:
            return ", ".join(self.client.transport.publishers_of(topic) or ())

        tracker = None if self._ours(TRACKER_NODE) else publishers(self.profile.tracks.topic)
        if self._ours(PLANNER_NODE):
            return AttackedPlanner(self.planner, tracker_node=tracker)
        node = publishers(self.profile.plan.topic)
        return AttackedPlanner(EXTERNAL, node, tracker, self.client.versions.get(node.rsplit("/", 1)[-1]))

    def _ours(self, node: str) -> bool:
        """Whether the graph's `node` is ours: started by us, or announced on /attack/nodes (the launch
        file configures it from the same params)."""
        return self.execution.spawn_nodes or node in self.client.present

    @property
    def perception_ahead(self) -> bool:
        """Whether the player may run the ground truth a frame ahead of the ego (docs/graph.md,
        "Perception one frame ahead"): only for our tracker and planner, which pair their inputs by
        stamp, and only when messages drive the planner; a team's node may take the latest message
        it holds instead, which would then be a frame early."""
        return self.execution.drive == "messages" and self._ours(TRACKER_NODE) and self._ours(PLANNER_NODE)

    @property
    def tracks_confirmed(self) -> bool:
        """Whether the player, under the clock drive, advances /clock only once our tracker confirms
        that every reader holds the frame's tracks (ros/lockstep.py): our tracker does; a team's
        tracker does not, and the attack's `reproduced` is the check there (docs/stacks.md)."""
        return self.execution.drive == "clock" and self._ours(TRACKER_NODE)

    def _warm_up(self, deadline: float, purpose: str) -> None:
        """One ground-truth rollout through every edge (`purpose` names it in a failure); re-sent when
        it stalls, with the stall allowed doubling each time (a lost first message costs little, a
        slow planner still passes). One that ends inconclusive is re-sent too until the deadline: a
        node that has not yet got a latched message (an external planner answering before /ego/route
        reached it) answers so; one that stays inconclusive is left for the search's own ground-truth
        rollout to report."""
        none = PerceptionErrors.none(*self.scenario.agents.shape)
        stall = WARMUP_STALL
        while True:
            rollout = self.client.send(none, self.perception_ahead, self.tracks_confirmed)
            try:
                done = self.client.collect(rollout, stall, self._recording, self.processes.dead)
                if done.status != Status.INCONCLUSIVE or time.monotonic() > deadline:
                    return
                log.info(f"warm-up rollout {rollout} inconclusive ({done.reason}); sending another")
            except RolloutFault as fault:
                mismatch = qos_mismatch(self.client.transport, self.profile)
                if mismatch is not None:  # no re-sending makes such a publisher match
                    raise GraphError(f"the graph did not complete {purpose}: {mismatch}") from None
                if self._gone() is not None or time.monotonic() > deadline:
                    raise GraphError(f"the graph did not complete {purpose}: {self._named(fault)}") from None
            stall *= 2

    def _gone(self) -> str | None:
        """How a node the graph needs went for good, if one did: a child process that exited (the
        nodes we start), or a running node that left the ROS graph (`left_the_graph`)."""
        if self.execution.spawn_nodes:
            return self.processes.dead()
        return left_the_graph(self.client.transport, self._watched, self.profile)

    def _watch(self) -> Callable[[], str | None]:
        """`_gone` as a rollout's wait calls it at every spin: the processes each time (a poll), the
        ROS graph once per `LOOK_EVERY` (a query of the middleware)."""
        if self.execution.spawn_nodes:
            return self.processes.dead
        looked = [0.0]

        def look() -> str | None:
            if time.monotonic() - looked[0] < LOOK_EVERY:
                return None
            looked[0] = time.monotonic()
            return self._gone()
        return look

    def _stop_if_gone(self, running: int | None, seen: str = "") -> None:
        """`NodeGone` when a node the graph needs is gone (`running`: the rollout it was in; `seen`: how
        the player saw it go, which bare DDS tells of a node not ours where nothing else can)."""
        gone = self._gone() or seen or None
        if gone is not None:
            during = f"in rollout {running}, " if running is not None else ""
            raise NodeGone(f"the search stops, as every rollout after would be inconclusive: {during}{gone}")

    def _named(self, fault: RolloutFault) -> str:
        """A fault's text with who the graph shows for what the frame waited on (`silence_suspects`)."""
        suspects = silence_suspects(self.client.transport, self.client.present, self.profile)
        return f"{fault} ({suspects})" if suspects else str(fault)

    def _restart(self) -> None:
        """Fresh node processes and a fresh participant (the old latched /attack/errors goes with
        it); nodes we did not start are left as they are."""
        if self.execution.spawn_nodes:
            self.processes.stop(kill=True)
            if self._given_transport is None:
                self._close_own_transport()
                self._client = None
            else:  # the dead nodes' announcements are gone with them
                self.client.announced.clear()
            self._start("the warm-up rollout of the restarted nodes")

    def close(self) -> None:
        """Stop the children (SIGTERM, then SIGKILL) and the transport; idempotent."""
        self.processes.close()
        self._close_own_transport()
        self._client = None

    def __enter__(self) -> "GraphRollouts":
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.close()

    # -- rollouts --------------------------------------------------------------------------------

    def rollout(self, errors: PerceptionErrors, record: bool = False) -> RolloutResult:
        self._stop_if_gone(None)  # a node known gone is not waited for
        if record and not self._recording:
            self._recording = True
            self.client.record_too()
            self._warm_up(time.monotonic() + STARTUP_TIMEOUT, RECORD_CHECK)  # proves the new subscriptions
        client = self.client
        rollout = client.send(errors, self.perception_ahead, self.tracks_confirmed)
        try:
            done = client.collect(rollout, self.execution.graph_timeout + GRACE, record, self._watch())
        except RolloutFault as raised:
            self._stop_if_gone(rollout, raised.gone)
            fault = self._named(raised)
            log.error(f"rollout {rollout} inconclusive: {fault}; "
                      + ("restarting the graph nodes" if self.execution.spawn_nodes
                         else "going on with the running nodes"))
            result = self._judged(client.received, frames_in(client.received, self._stamps),
                              f"graph failure in rollout {rollout}: {fault}", None)
            if record:  # the attack bag is still written, without tracks and plans
                result.tracks, result.plans = [], []
            self._restart()
            return result
        if done.reason:
            log.warning(f"rollout {rollout} {done.status}: {done.reason}")
        recorded = kept_frames(client.received, self._stamps, done, self.stop_at_collision) if record else None
        result = self._judged(client.received, done.frames, done.reason or None, recorded)
        self.observe(errors, result)
        return result

    def observe(self, errors: PerceptionErrors, result: RolloutResult) -> None:
        """A rollout of the scenario, run here or answered elsewhere (`ResumedRollouts`, from a checkpoint):
        the first conclusive one on perfect perception is the ground truth's rollout, which the rule
        monitor judges rollouts against (phantom braking, progress), published once on /attack/reference."""
        perfect = errors.equals(PerceptionErrors.none(*errors.shape, errors.kinds, errors.ghost_slots))
        if self._reference is not None or result.inconclusive is not None or not perfect:
            return
        self._reference = ReferenceDrive(np.array(result.ego, dtype=float), self.scenario.dt)
        self.client.reference.publish(reference_message(self._reference))

    def _judged(self, received: dict, frames: int, inconclusive: str | None,
                recorded: tuple[int, int] | None) -> RolloutResult:
        """The result of what the graph published, judged as the embedded rollout judges its own."""
        result = assemble(received, self._stamps, self._slots, frames, inconclusive, recorded, self.client.plan)
        return judge(result, self.scenario, self._config)


def watch(transport: Transport, present: dict[str, int], profile: Profile) -> Watched:
    """What `left_the_graph` will miss of a graph that is up: nothing over bare DDS (no node names)."""
    nodes = transport.node_names()
    if nodes is None:
        return Watched()
    publishers = {topic: transport.publishers_of(topic) or () for topic in (profile.plan.topic, profile.tracks.topic)}
    return Watched(frozenset(present) - frozenset(_gone_from(nodes, present)),
                   {topic: names for topic, names in publishers.items() if names})


def left_the_graph(transport: Transport, watched: Watched, profile: Profile) -> str | None:
    """How a running node the graph needs left it, if one did: announced on /attack/nodes and no longer
    in the ROS graph, or publishing the plans or tracks when the graph came up and no node does now.
    None over bare DDS, which names no nodes (a rollout then times out, its frame naming what it waited on)."""
    nodes = transport.node_names()
    if nodes is None:
        return None
    gone = _gone_from(nodes, watched.nodes)
    if gone:
        return (f"the node{'s' * (len(gone) > 1)} {', '.join(gone)} left the ROS graph (announced on {PRESENCE}, "
                "no longer in it)")
    for what, topic in (("plans", profile.plan.topic), ("tracked objects", profile.tracks.topic)):
        if topic in watched.publishers and not transport.publishers_of(topic):
            return (f"{', '.join(watched.publishers[topic])} left the ROS graph: no node publishes {what} on {topic} "
                    "any more")
    return None


def _gone_from(nodes: tuple[str, ...], announced: Iterable[str]) -> list[str]:
    """The names announced on /attack/nodes that no node of the ROS graph (`nodes`) bears."""
    return sorted(name for name in announced if not any(node.rsplit("/", 1)[-1] == name for node in nodes))


def qos_mismatch(transport: Transport, profile: Profile) -> str | None:
    """A team's node publishing the plans or the tracked objects best effort, which our reliable
    subscribers never match, where the transport sees publishers' QoS (rclpy; not bare DDS)."""
    for what, topic in (("plans", profile.plan.topic), ("tracked objects", profile.tracks.topic)):
        nodes = transport.best_effort_publishers(topic)
        if nodes:
            return (f"{', '.join(nodes)} publish{'es' * (len(nodes) == 1)} {what} on {topic} best effort, which our "
                    "reliable subscribers never match: publish them reliable (docs/graph.md, the QoS of the topics)")
    return None


def silence_suspects(transport: Transport, present: dict[str, int], profile: Profile) -> str:
    """Who should have answered a frame that timed out, as the ROS graph shows them: the nodes
    publishing the plans and the tracked objects (or that none does: a planner that died at start,
    or was never started), and the nodes that announced themselves on /attack/nodes but have left
    the graph since. "" over bare DDS, which names no nodes; the nodes we start there are watched as
    processes, and their deaths named by those."""
    nodes = transport.node_names()
    if nodes is None:
        return ""
    mismatch = qos_mismatch(transport, profile)
    said = [mismatch] if mismatch is not None else []
    for what, topic in (("plans", profile.plan.topic), ("tracked objects", profile.tracks.topic)):
        publishers = transport.publishers_of(topic) or ()
        said.append(f"{what} on {topic} come from {', '.join(publishers)}" if publishers
                    else f"no node publishes {what} on {topic}")
    gone = _gone_from(nodes, present)
    if gone:
        said.append(f"gone since they announced themselves on {PRESENCE}: {', '.join(gone)}")
    return "; ".join(said)
