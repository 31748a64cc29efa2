"""The package as ROS users run it, against a real ROS 2 Jazzy (CI's second run sources the kit):

- a colcon workspace: `ros2 run advperc_ros orchestrator` and `ros2 launch advperc_ros
  attack.launch.py`, from a folder that is not the repository, write the report `advperc attack`
  writes; a team's own nodes in its place (`planner:=external`, `tracker:=external`) are attacked
  and named in the report;
- the live graph matches the contract table of docs/graph.md (nodes, topics, types, QoS);
- a mixed graph (some nodes over rclpy, the others over our bare Cyclone transport) gives the
  embedded report: the bare-DDS transport interoperates with rmw_cyclonedds;
- rosbag2: `ros2 bag info` lists every topic of our bags, `ros2 bag play` feeds the graph.

All DDS traffic stays on loopback (activate.sh's CYCLONEDDS_URI for ROS, `dds.localhost_only` for
ours), each test on a domain id of its own (conftest.ros_domain).
"""

import contextlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO, REQUIRE_ROS, need_program, need_ros

from advperc_ros.nodes.graph_nodes import SPECS, ros_parameters
from advperc_ros.params import NODE, load_params
from advperc_ros.ros import bag as bags
from advperc_ros.ros import topics

SMALL_SEARCH = {"heuristic": {"iterations": 1}, "random": {"steps": 4}, "refine": {"iterations": 0}}
"""A short search (about a dozen rollouts): what is compared is the plumbing, not the search."""
WALL_CLOCK = ("wall_time_s",)
TIMEOUT = 300


def _report(folder: Path) -> dict:
    report = json.loads((folder / "report.json").read_text())
    return {key: value for key, value in report.items() if key not in WALL_CLOCK}


def _small_params(folder: Path, source: Path, **changes) -> Path:
    """`source` (a bundled params file) with the short search, written into `folder`."""
    document = yaml.safe_load(source.read_text())
    document[NODE]["ros__parameters"]["search"] = SMALL_SEARCH
    document[NODE]["ros__parameters"].update(changes)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / source.name
    path.write_text(yaml.safe_dump(document))
    return path


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> Path:
    """A colcon workspace with this package built into it, as a ROS user installs it."""
    need_ros("rclpy")
    need_program("colcon")
    ws = tmp_path_factory.mktemp("ws")
    source = ws / "src" / "advperc_ros"
    tracked = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=True).stdout
    for name in filter(None, tracked.decode().split("\0")):
        if (REPO / name).is_file():
            (source / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / name, source / name)
    subprocess.run(["colcon", "build", "--packages-select", "advperc_ros"], cwd=ws, check=True,
                   capture_output=True, timeout=TIMEOUT)
    return ws


def _orchestrator_lines(output: str) -> str:
    """What the orchestrators and the nodes that died said in a launch (each node's lines start with
    `[<executable>-<n>]`): where a missing report is explained."""
    died = set(re.findall(r"\[ERROR\] \[([\w-]+)\]: process has died", output))
    return "\n".join(line for line in output.splitlines() if "orchestrator" in line or "ERROR" in line
                     or any(line.startswith(f"[{name}]") for name in died))[-6000:]


def _ended(process: subprocess.Popen, timeout: float = TIMEOUT) -> tuple[int, str]:
    """(exit code, output) of a launch, a run or a team's node, which must end without a traceback on
    every path (success, refusal, Ctrl-C): the many launches of this module are the shutdown check
    (the scenario player's wait set once failed at shutdown in 2 of 9 launches)."""
    try:
        output, _ = process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, 9)
        output, _ = process.communicate()
        raise AssertionError(f"still running after {timeout} s: {output[-3000:]}")
    assert "Traceback" not in output, output[-4000:]
    return process.returncode, output


def _finish(process: subprocess.Popen, timeout: float = TIMEOUT) -> str:
    code, output = _ended(process, timeout)
    assert code == 0, output[-3000:]
    return output


# ----- docs/graph.md: the contract table ----------------------------------------------------------------

def _contract() -> dict[str, tuple[str, str]]:
    """docs/graph.md's topic table: topic -> (type, QoS: 'volatile' or 'latched')."""
    text = (REPO / "docs" / "graph.md").read_text()
    rows = re.findall(r"^\| `(/[\w/]+)` \| `([\w/]+)` \| (volatile|latched) \|", text, flags=re.M)
    assert len(rows) >= 14, "docs/graph.md lost its topic table"
    return {topic: (msgtype, qos) for topic, msgtype, qos in rows}


def _node_table() -> dict[str, tuple[set[str], set[str]]]:
    """docs/graph.md's node table: node -> (topics it subscribes, topics it publishes); topics in
    parentheses (only for the recorded rollout) are left out."""
    text = (REPO / "docs" / "graph.md").read_text().split("\n## Nodes\n")[1].split("\n## ")[0]
    out = {}
    for name, subscribes, publishes in re.findall(r"^\| `(\w+)` \| [^|]* \| ([^|]*) \| ([^|]*) \|$", text, flags=re.M):
        def named(cell: str) -> set[str]:
            return set(re.findall(r"/[\w/]+", re.sub(r"\(.*?\)", "", cell)))
        out[name] = (named(subscribes), named(publishes))
    assert set(out) == {"scenario_player", "error_injector", "tracker", "planner", "rule_monitor", "orchestrator"}
    return out


def test_docs_topic_table_is_the_code_s():
    """Types and QoS of the contract table are those the code uses (the live graph is checked below)."""
    for topic, (msgtype, qos) in _contract().items():
        assert topics.TOPIC_TYPES.get(topic, "std_msgs/msg/String") == msgtype, topic
        latched = topic in topics.LATCHED or topic in ("/attack/errors", "/attack/nodes")
        assert (qos == "latched") == latched, topic


def _live_graph(domain: int, expected_nodes: set[str], deadline: float) -> dict:
    """The graph as rclpy sees it once `expected_nodes` are all up: per node its publishers and
    subscriptions with types, and per topic its endpoints' QoS."""
    import rclpy
    from rclpy.node import Node

    rclpy.init(domain_id=domain)
    try:
        probe = Node("advperc_contract_probe")
        while time.monotonic() < deadline:
            names = {name for name, _ in probe.get_node_names_and_namespaces()}
            if expected_nodes <= names:
                break
            time.sleep(0.2)
        else:
            raise AssertionError(f"nodes never all up: {sorted(expected_nodes - names)} missing")
        table = _node_table()
        graph = {"nodes": {}, "qos": {}}
        while True:  # discovery brings a node's name before all its endpoints: wait for what the docs list
            for name in expected_nodes:
                graph["nodes"][name] = (dict(probe.get_subscriber_names_and_types_by_node(name, "/")),
                                        dict(probe.get_publisher_names_and_types_by_node(name, "/")))
            complete = all(table[name][0] <= set(graph["nodes"][name][0]) and table[name][1] <= set(graph["nodes"][name][1])
                           for name in expected_nodes)
            if complete or time.monotonic() > deadline:
                break
            time.sleep(0.2)
        for topic in _contract():
            endpoints = probe.get_publishers_info_by_topic(topic) + probe.get_subscriptions_info_by_topic(topic)
            graph["qos"][topic] = [(e.node_name, e.qos_profile) for e in endpoints]
        probe.destroy_node()
        return graph
    finally:
        rclpy.try_shutdown()


def _check_contract(graph: dict) -> None:
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

    contract = _contract()
    for name, (subscribes, publishes) in _node_table().items():
        live_subs, live_pubs = graph["nodes"][name]
        own = {t: types for t, types in live_subs.items() if not t.startswith("/parameter_events")}
        assert subscribes <= set(own), f"{name} does not subscribe {sorted(subscribes - set(own))}"
        for topic in subscribes:
            assert own[topic] == [contract[topic][0]], (name, topic, own[topic])
        pubs = {t: types for t, types in live_pubs.items() if t not in ("/rosout", "/parameter_events")}
        assert set(pubs) == publishes, f"{name} publishes {sorted(pubs)}, docs say {sorted(publishes)}"
        for topic in publishes:
            assert pubs[topic] == [contract[topic][0]], (name, topic, pubs[topic])
    for topic, endpoints in graph["qos"].items():
        for node, qos in endpoints:
            assert qos.reliability == ReliabilityPolicy.RELIABLE, (topic, node)
            latched = contract[topic][1] == "latched"
            durability = DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE
            assert qos.durability == durability, (topic, node, qos.durability)


# ----- a colcon workspace, as a ROS user runs the package -----------------------------------------------

def test_readme_ros_section_runs_as_written(workspace, ros_domain):
    """The ROS 2 block of docs/ros2.md (once the README's), verbatim, from the workspace root, not the
    repository (it builds the package again; the bags are found in the installed share); while its
    launch file runs, the live graph is checked against docs/graph.md's contract tables."""
    readme = (REPO / "docs" / "ros2.md").read_text().split("\n## The ROS 2 way\n")[1]
    block = re.search(r"```bash\n(.*?)\n```", readme, flags=re.S).group(1)
    results = workspace / "results"
    shutil.rmtree(results, ignore_errors=True)
    run = subprocess.Popen(["bash", "-e", "-c", block], cwd=workspace, stdout=subprocess.PIPE,
                           stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:  # the first launch is the only time all six of our nodes are up (the third leaves our planner out)
        graph = _live_graph(ros_domain, {"scenario_player", "error_injector", "tracker", "planner", "rule_monitor",
                                         "orchestrator"}, time.monotonic() + 2 * TIMEOUT)
    except BaseException:
        os.killpg(run.pid, 9)
        run.communicate()
        raise
    output = _finish(run, timeout=2 * TIMEOUT)
    _check_contract(graph)
    for way in ("run", "launch"):
        assert (results / way / "report.json").is_file(), (way, _orchestrator_lines(output))
    expected = _report(results / "run")  # `ros2 run` embedded: attack_to_folder, as `advperc attack` runs it
    assert expected["collision"] and _report(results / "launch") == expected


# ----- a mixed graph: rclpy and bare Cyclone nodes on one domain ----------------------------------------

def _node_params(folder: Path, params_file: Path) -> Path:
    """The ROS params file of every graph node (the launch file's parameters), from an orchestrator's params file."""
    params = load_params(params_file)
    path = folder / "nodes.yaml"
    path.write_text(yaml.safe_dump({spec.name: {"ros__parameters": ros_parameters(spec, params, params.bag)}
                                    for spec in SPECS}))
    return path


@pytest.mark.parametrize("over_rclpy", [("scenario_player", "error_injector", "tracker"), ("planner", "rule_monitor"), ()],
                         ids=["player-injector-tracker-rclpy", "planner-rule-rclpy", "all-cyclone-no-ros"])
def test_a_mixed_graph_gives_the_embedded_report(tmp_path, fresh_domain, over_rclpy):
    """Nodes started by hand (`graph.spawn_nodes: false`, as the bare-DDS recipe of docs/planner-node.md
    does), some over rclpy where given, the others and the orchestrator over bare Cyclone."""
    if over_rclpy:
        need_ros("rclpy")
    params_file = _small_params(tmp_path, REPO / "config" / "idm_lane_following.yaml",
                                bag=str(REPO / "bags" / "idm_lane_following"),
                                dds={"domain_id": fresh_domain, "localhost_only": True},
                                graph={"spawn_nodes": False, "timeout": 10.0}, rollout_backend="graph")
    ros_params = _node_params(tmp_path, params_file)
    nodes = []
    try:
        for spec in SPECS:
            rest = (["--ros-args", "--params-file", str(ros_params)] if spec.name in over_rclpy
                    else ["--params-file", str(params_file), "--exit-with-parent"])
            # stderr into a file, which never fills as an unread pipe would; faulthandler: a hung node's stacks
            with (tmp_path / f"{spec.name}.log").open("w") as log:
                nodes.append(subprocess.Popen([sys.executable, "-X", "faulthandler", "-m", f"advperc_ros.nodes.{spec.name}",
                                               *rest], stdout=subprocess.DEVNULL, stderr=log))
        graph = subprocess.run([sys.executable, "-m", "advperc_ros.cli", "attack", str(params_file), "--output",
                                str(tmp_path / "graph"), "--quiet"], capture_output=True, text=True, timeout=TIMEOUT)
        assert graph.returncode == 0, graph.stderr
    finally:
        _stop(nodes, tmp_path)
    embedded = subprocess.run([sys.executable, "-m", "advperc_ros.cli", "attack", str(params_file), "--backend",
                               "embedded", "--output", str(tmp_path / "embedded"), "--quiet"],
                              capture_output=True, text=True, timeout=TIMEOUT)
    assert embedded.returncode == 0, embedded.stderr
    assert _report(tmp_path / "graph") == _report(tmp_path / "embedded")
    assert all(node.returncode == 0 for node in nodes), [(spec.name, (tmp_path / f"{spec.name}.log").read_text()[-500:])
                                                         for spec, node in zip(SPECS, nodes) if node.returncode]


def _dying_planner(tmp_path: Path, monkeypatch, **changes) -> tuple[Path, Path]:
    """The params of a short graph attack on nodes started by hand whose planner's process exits at the
    first plan of its fourth rollout (test_graph.ExitingPlanner), and the file where it writes how many
    rollouts it saw."""
    frames = bags.read_scenario(REPO / "bags" / "idm_lane_following").num_frames
    seen = tmp_path / "rollouts_seen"
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(REPO / "test" / "backends"), str(REPO / "test"),
                                                      os.environ.get("PYTHONPATH", "")]))
    monkeypatch.setenv("ADVPERC_TEST_EXIT_AFTER", f"{3 * frames}:{seen}")
    return _small_params(tmp_path, REPO / "config" / "idm_lane_following.yaml",
                         bag=str(REPO / "bags" / "idm_lane_following"), planner="test_graph:ExitingPlanner",
                         graph={"spawn_nodes": False, "timeout": 5.0}, rollout_backend="graph", **changes), seen


def test_a_team_s_planner_that_dies_mid_search_stops_it_naming_the_node_gone(tmp_path, ros_domain, monkeypatch):
    """Issue 51: the team's own rclpy planner crashed, and the search ran on against it some 50 rollouts of a
    timeout each, though it had reported it gone. Now the orchestrator sees it leave the ROS graph and stops:
    exit 4, one error line naming it, the checkpoint kept."""
    need_ros("rclpy")
    params_file, seen = _dying_planner(tmp_path, monkeypatch)
    ros_params = _node_params(tmp_path, params_file)
    nodes = []
    try:
        for spec in SPECS:
            with (tmp_path / f"{spec.name}.log").open("w") as log:
                nodes.append(subprocess.Popen([sys.executable, "-m", f"advperc_ros.nodes.{spec.name}", "--ros-args",
                                               "--params-file", str(ros_params)], stdout=subprocess.DEVNULL, stderr=log))
        output = tmp_path / "attack"
        started = time.monotonic()
        orchestrator = "from advperc_ros.orchestrator_node import main; raise SystemExit(main())"
        run = subprocess.run([sys.executable, "-c", orchestrator, "--ros-args", "--params-file", str(params_file),
                              "-p", f"output:={output}"], capture_output=True, text=True, timeout=TIMEOUT)
        print(f"the attack ended {time.monotonic() - started:.1f} s after it started")  # never asserted
    finally:
        with contextlib.suppress(subprocess.TimeoutExpired):  # the planner exits by itself; the others are stopped
            nodes[[spec.name for spec in SPECS].index("planner")].wait(timeout=30)
        _stop(nodes, tmp_path)
    errors = [line for line in run.stderr.splitlines() if "[ERROR]" in line]
    assert run.returncode == 4 and len(errors) >= 1, run.stderr[-3000:]
    assert "the search stops" in errors[-1] and "planner left the ROS graph" in errors[-1], errors
    assert "resume:=true" in errors[-1] and "attacking our planner node (test_graph:ExitingPlanner)" in run.stderr
    checkpointed = (output.parent / f".{output.name}.checkpoint" / "rollouts.jsonl").read_text().splitlines()
    assert 1 <= len(checkpointed) <= int(seen.read_text())  # at most one rollout waited on the planner once it died


def test_a_planner_that_dies_mid_search_over_bare_dds_stops_it_naming_the_plans_nobody_publishes(
        tmp_path, fresh_domain, monkeypatch):
    """Issue 51 over bare DDS, which names no nodes: a planner started by hand died, and each rollout after
    cost a timeout. Now the player's reader of the plans matches no publisher once the dead process's DDS
    lease ends, the frame's timeout says so, and the search stops: exit 4, the checkpoint kept, within a
    few rollouts (Cyclone's lease is 10 s, the frame's timeout here 5 s)."""
    params_file, seen = _dying_planner(tmp_path, monkeypatch, dds={"domain_id": fresh_domain, "localhost_only": True})
    nodes = []
    try:
        for spec in SPECS:
            with (tmp_path / f"{spec.name}.log").open("w") as log:
                nodes.append(subprocess.Popen([sys.executable, "-m", f"advperc_ros.nodes.{spec.name}", "--params-file",
                                               str(params_file), "--exit-with-parent"], stdout=subprocess.DEVNULL,
                                              stderr=log))
        output = tmp_path / "attack"
        run = subprocess.run([sys.executable, "-m", "advperc_ros.cli", "attack", str(params_file), "--output",
                              str(output), "--quiet"], capture_output=True, text=True, timeout=TIMEOUT)
    finally:
        with contextlib.suppress(subprocess.TimeoutExpired):  # the planner exits by itself; the others are stopped
            nodes[[spec.name for spec in SPECS].index("planner")].wait(timeout=30)
        _stop(nodes, tmp_path)
    assert run.returncode == 4, run.stderr[-3000:]
    assert "the search stops" in run.stderr and "no node publishes plans on /planning/trajectory (never started, " \
        "ended, or left the DDS domain)" in run.stderr, run.stderr[-3000:]
    assert "--resume" in run.stderr and not output.exists()
    checkpointed = (output.parent / f".{output.name}.checkpoint" / "rollouts.jsonl").read_text().splitlines()
    assert 1 <= len(checkpointed) <= int(seen.read_text())  # the rollouts before its death, none after


def _stop(nodes: list[subprocess.Popen], logs: Path) -> None:
    """SIGINT to every node, as Ctrl-C; a node still running 30 s later is hung: SIGABRT makes faulthandler
    write its threads' stacks into its log, which the failure shows."""
    for node in nodes:
        node.send_signal(signal.SIGINT)
    for spec, node in zip(SPECS, nodes):
        try:
            node.wait(timeout=30)
        except subprocess.TimeoutExpired:
            node.send_signal(signal.SIGABRT)
            node.wait(timeout=30)
            raise AssertionError(f"{spec.name} did not stop on SIGINT: {(logs / f'{spec.name}.log').read_text()[-4000:]}")


# ----- rosbag2 ------------------------------------------------------------------------------------------

def _bag_info(path: Path) -> tuple[str, dict[str, tuple[str, int]]]:
    run = subprocess.run(["ros2", "bag", "info", str(path)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    distro = re.search(r"ROS Distro:\s+(\S+)", run.stdout).group(1)
    listed = {topic: (msgtype, int(count)) for topic, msgtype, count in
              re.findall(r"Topic: (\S+) \| Type: (\S+) \| Count: (\d+)", run.stdout)}
    return distro, listed


def _recorded(path: Path) -> dict[str, tuple[str, int]]:
    """Every topic of a bag as rosbags reads it: (type, count)."""
    return {topic: (msgtype, count) for topic, (msgtype, count) in bags.bag_topics(path).items()}


def test_ros2_bag_info_lists_every_topic_of_our_bags(tmp_path, ros_domain):
    need_program("ros2")
    ground_truth = sorted((REPO / "bags").iterdir())
    attack = subprocess.run([sys.executable, "-m", "advperc_ros.cli", "attack",
                             str(_small_params(tmp_path, REPO / "config" / "idm_lane_following.yaml",
                                               bag=str(REPO / "bags" / "idm_lane_following"),
                                               graph={"interface": "autoware"})),
                             "--output", str(tmp_path / "out"), "--quiet"], capture_output=True, text=True, timeout=TIMEOUT)
    assert attack.returncode == 0, attack.stderr
    for path in [*ground_truth, tmp_path / "out" / "attack"]:
        distro, listed = _bag_info(path)
        assert distro == "jazzy" and listed == _recorded(path), path
    listed = _bag_info(tmp_path / "out" / "attack")[1]
    assert {topics.PERCEPTION, topics.TRACKING, topics.PLAN, topics.RULE} <= set(listed)
    # under the Autoware profile the attacked layers in Autoware's own types too, as its tools read them
    assert listed["/perception/object_recognition/detection/objects"][0] == "autoware_perception_msgs/msg/DetectedObjects"
    assert listed["/perception/object_recognition/objects"][0] == "autoware_perception_msgs/msg/PredictedObjects"
    assert listed["/planning/scenario_planning/trajectory"][0] == "autoware_planning_msgs/msg/Trajectory"
    assert listed["/localization/kinematic_state"] == listed[topics.ODOMETRY]


def test_a_silent_frame_names_who_the_ros_graph_shows_for_it(ros_domain):
    """silence_suspects over rclpy's graph API: the tracker publishing, nobody publishing plans, and
    our planner node, which announced itself, gone from the graph."""
    import rclpy
    from rclpy.node import Node

    from advperc_ros.backends.graph.rollouts import silence_suspects
    from advperc_ros.ros.interfaces.registry import load_profile
    from advperc_ros.ros.transport import RclpyTransport

    profile = load_profile("advperc")
    rclpy.init(domain_id=ros_domain)
    try:
        probe, tracker = Node("advperc_suspects_probe"), Node("advperc_suspects_tracker")
        RclpyTransport(tracker).publisher(profile.tracks.topic, profile.tracks.msgtype)
        transport = RclpyTransport(probe)
        expected = (f"no node publishes plans on {profile.plan.topic}; tracked objects on {profile.tracks.topic} come "
                    "from /advperc_suspects_tracker; gone since they announced themselves on /attack/nodes: planner")
        deadline = time.monotonic() + 30
        while (said := silence_suspects(transport, {"planner": 1, "advperc_suspects_tracker": 2}, profile)) != expected:
            assert time.monotonic() < deadline, said
            time.sleep(0.1)
        tracker.destroy_node()
        probe.destroy_node()
    finally:
        rclpy.try_shutdown()


def test_ros2_bag_play_feeds_ground_truth_the_graph_accepts(ros_domain):
    need_program("ros2")
    import rclpy
    from rclpy.node import Node

    from advperc_ros.nodes.runtime import ground_truth_objects
    from advperc_ros.ros.transport import RclpyTransport

    path = REPO / "bags" / "idm_overtake_follow"
    scenario = bags.read_scenario(path)
    rclpy.init(domain_id=ros_domain)
    player = None
    try:
        node = Node("advperc_bag_listener")
        received: dict[int, dict] = {}

        def keep(data: bytes) -> None:
            stamp, objects = ground_truth_objects(data)  # what the injector and rule monitor do with it
            received[stamp] = objects

        transport = RclpyTransport(node)
        transport.subscriber(topics.GROUND_TRUTH, topics.TOPIC_TYPES[topics.GROUND_TRUTH], callback=keep, raw=True)
        player = subprocess.Popen(["ros2", "bag", "play", str(path), "--rate", "5", "--topics", topics.GROUND_TRUTH,
                                   "--delay", "1"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 120
        while len(received) < scenario.num_frames and time.monotonic() < deadline:
            transport.spin_once(0.1)
        assert player.wait(timeout=60) == 0, player.stderr.read()
        assert sorted(received) == [int(s) for s in scenario.stamps_ns]
        for k, stamp in enumerate(scenario.stamps_ns):
            expected = scenario.agents.frame(k)
            objects = received[int(stamp)]
            order = np.argsort(objects["ids"])
            assert np.array_equal(objects["ids"][order], np.sort(expected["ids"]))
            assert np.allclose(objects["x"][order], expected["x"][np.argsort(expected["ids"])], atol=1e-9)
        node.destroy_node()
    finally:
        if player is not None and player.poll() is None:
            player.kill()
        rclpy.try_shutdown()


def test_a_log_recorded_by_ros2_bag_record_imports_as_the_log_it_was_published_from(ros_domain, tmp_path):
    """A team's log as rosbag2 itself writes one: `ros2 bag record` (its MCAP writer, metadata and QoS, and
    log times that are the moments of reception, not the stamps) of Autoware's objects, the ego's odometry
    and the map while they are published live, by `ros2 bag play` of the log test_import_bag writes of a
    bundled scenario. `advperc import-bag` makes the same ground-truth bag of both logs, to the bit, so the
    recorded one gives the bundled bag's attack as the written one does (test_import_bag)."""
    need_program("ros2")
    from test_import_bag import BUNDLED, OBJECTS, ODOMETRY, autoware_log

    from advperc_ros.cli import main

    source = autoware_log(tmp_path / "source", bags.read_scenario(BUNDLED), with_map=True)
    recorded = tmp_path / "recorded"
    wanted = [OBJECTS, ODOMETRY, topics.LANES, topics.ROUTE]
    recorder = subprocess.Popen(["ros2", "bag", "record", "-s", "mcap", "-o", str(recorded), "--topics", *wanted],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        # play's publishers exist during its delay, so the recorder subscribes to each before its first message
        player = subprocess.run(["ros2", "bag", "play", str(source), "--rate", "5", "--delay", "3"],
                                capture_output=True, text=True, timeout=TIMEOUT)
        assert player.returncode == 0, player.stderr[-3000:]
        time.sleep(1.0)
    finally:
        os.killpg(recorder.pid, signal.SIGINT)
    code, log = _ended(recorder, timeout=60)
    assert code == 0, log[-3000:]
    played, got = _recorded(source), _recorded(recorded)
    assert got == played, log[-3000:]  # every message of every topic, none lost
    received, _ = bags.read_topics(recorded, [OBJECTS], raw=True)
    stamps = bags.read_scenario(BUNDLED).stamps_ns
    assert received[OBJECTS][0][0] - stamps[0] > 10**9  # logged at the wall-clock moment of reception, not the stamp
    assert main(["import-bag", str(source), "--output", str(tmp_path / "from_source")]) == 0
    assert main(["import-bag", str(recorded), "--output", str(tmp_path / "from_record")]) == 0
    written, read_back = bags.read_scenario(tmp_path / "from_source"), bags.read_scenario(tmp_path / "from_record")
    assert np.array_equal(read_back.stamps_ns, written.stamps_ns) and read_back.ego_start == written.ego_start
    for field in ("ids", "valid", "x", "y", "yaw", "vx", "vy", "length", "width", "height"):
        assert np.array_equal(getattr(read_back.agents, field), getattr(written.agents, field)), field
    assert np.array_equal(read_back.route.points, written.route.points)
    assert [(lane.id, lane.width) for lane in read_back.lanes] == [(lane.id, lane.width) for lane in written.lanes]


def test_the_player_logs_failed_and_finished_rollouts_through_rclpys_logger():
    """rclpy's logger raises when one call site logs at two severities; the player logged an
    inconclusive rollout (warning) and a finished one (info) from one call, so a launch whose warm-up
    timed out died at its next rollout (seen in 1 of 3 launches)."""
    need_ros("rclpy")
    from rclpy.logging import get_logger

    from advperc_ros.nodes.scenario_player import ScenarioPlayer
    from advperc_ros.ros.lockstep import Status

    class Published(list):
        publish = list.append

    player = ScenarioPlayer.__new__(ScenarioPlayer)
    player._log, player._done = get_logger("test_scenario_player"), Published()
    for status in (Status.INCONCLUSIVE, Status.OK, Status.INCONCLUSIVE):
        player._run = type("Run", (), {"rollout": len(player._done), "frame": 3})()
        player._finish(status, "no plan" if status != Status.OK else "")
    assert len(player._done) == 3


# ----- failures a script or CI job must see: `ros2 launch` and `ros2 run` exit codes -----------------------

def _in_workspace(workspace: Path, command: str, domain: int) -> subprocess.Popen:
    """`command` in a shell that sourced the workspace, as a user's script runs it; its own process group."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
    return subprocess.Popen(["bash", "-c", f"source install/setup.bash && exec {command}"], cwd=workspace, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)


@pytest.mark.parametrize("arguments, line", [
    ("planer:=external", "unknown launch argument 'planer' (arguments: params, planner, tracker, output, resume, "
                         "interface, drive, rule, traffic)"),
    ("traffic:=ractive", "launch argument 'traffic' must be reactive or replayed, got 'ractive'"),
    ("interface:=ros1", "launch argument 'interface' must be one of advperc, autoware, autoware_tracked, vision_msgs, "
                        "got 'ros1'"),
    ("output:=x", "{missing}: no such params file"),
])
def test_a_launch_refused_before_any_node_starts_exits_2_with_one_line(workspace, ros_domain, tmp_path, arguments, line):
    params = tmp_path / "missing.yaml" if "missing" in line else REPO / "config" / "idm_lane_following.yaml"
    launch = _in_workspace(workspace, f"ros2 launch advperc_ros attack.launch.py params:={params} {arguments}", ros_domain)
    code, output = _ended(launch, timeout=120)
    errors = [text for text in output.splitlines() if "[ERROR]" in text]
    assert code == 2 and len(errors) == 1 and errors[0].endswith(line.format(missing=params)), output[-3000:]
    assert "process started" not in output, output[-3000:]


def test_a_launch_whose_planner_never_answers_exits_4_naming_who_is_silent(workspace, ros_domain, tmp_path):
    """`planner:=external` with no planner running (one that died at start, or was never started):
    the launch ends with exit code 4 and one line that says no node publishes the plans, not after
    minutes of retries with a line naming no one; nothing written."""
    params = _small_params(tmp_path, REPO / "config" / "idm_lane_following.yaml")
    launch = _in_workspace(workspace, f"ros2 launch advperc_ros attack.launch.py params:={params} planner:=external "
                                      f"output:={tmp_path / 'attack'}", ros_domain)
    code, output = _ended(launch, timeout=TIMEOUT)
    errors = [text for text in output.splitlines() if "[ERROR]" in text and "[orchestrator]" in text]
    assert code == 4 and len(errors) == 1, _orchestrator_lines(output)
    assert "no node publishes plans on /planning/trajectory" in errors[0], errors[0]
    assert sorted(path.name for path in tmp_path.iterdir()) == [params.name]


def test_a_launch_beside_a_planner_publishing_best_effort_exits_4_naming_its_qos(workspace, ros_domain, tmp_path):
    """Issue 51: a team's planner whose plans go out best effort, which our reliable subscriber never
    matches (rclpy warns once, mid-log): the launch ends with exit code 4 and one line naming the node
    and its QoS, not "no plan stamped 0 ... (a node is dead or silent)"; nothing written."""
    planner = tmp_path / "best_effort_planner.py"
    text = (REPO / "examples" / "external_planner.py").read_text()
    reliable = "depth=1000, reliability=ReliabilityPolicy.RELIABLE"
    assert text.count(reliable) == 1
    planner.write_text(text.replace(reliable, "depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT"))
    params = _small_params(tmp_path, REPO / "config" / "idm_lane_following.yaml")
    node = _in_workspace(workspace, f"python3 {planner}", ros_domain)
    try:
        launch = _in_workspace(workspace, f"ros2 launch advperc_ros attack.launch.py params:={params} planner:=external "
                                          f"output:={tmp_path / 'attack'}", ros_domain)
        code, output = _ended(launch, timeout=TIMEOUT)
    finally:
        os.killpg(node.pid, signal.SIGINT)
        _ended(node, timeout=60)
    errors = [text for text in output.splitlines() if "[ERROR]" in text and "[orchestrator]" in text]
    assert code == 4 and len(errors) == 1, _orchestrator_lines(output)
    assert ("/external_planner publishes plans on /planning/trajectory best effort, which our reliable subscribers "
            "never match") in errors[0], errors[0]
    assert not (tmp_path / "attack").exists()


@pytest.fixture(scope="module")
def ros_only_python(tmp_path_factory) -> Path:
    """A venv holding only what the ROS 2 tools themselves import (the kit's pip-runtime.txt), none of
    the package's dependencies: the interpreter `ros2` runs on a machine whose team keeps those in a venv."""
    runtime = REPO.parent / "shared" / "ros2" / "pip-runtime.txt"
    if not runtime.is_file():
        (pytest.fail if REQUIRE_ROS else pytest.skip)(f"{runtime} is missing: the ROS 2 kit is not beside the repository")
    venv = tmp_path_factory.mktemp("ros-only-venv")
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, capture_output=True, timeout=TIMEOUT)
    subprocess.run([str(venv / "bin" / "pip"), "install", "-q", *runtime.read_text().split()], check=True,
                   capture_output=True, timeout=TIMEOUT)
    python = venv / "bin" / "python"
    assert subprocess.run([str(python), "-c", "import filterpy"], capture_output=True).returncode != 0
    return python


@pytest.mark.parametrize("arguments, code", [("", 0), ("planner:=elsewhere", 2)])
def test_a_launch_works_when_ros2_runs_on_an_interpreter_without_the_package_s_dependencies(
        workspace, ros_domain, tmp_path, ros_only_python, arguments, code):
    """`ros2` on an interpreter that has ROS 2's own modules and not the package's dependencies (they
    live in the venv that built the workspace): the launch file imports nothing of the package, its
    `launch_plan` executable (the building interpreter's) checks the params, so the attack runs, and a
    refusal is still one line and exit code 2 before any node starts."""
    params = _small_params(tmp_path, REPO / "config" / "idm_lane_following.yaml")
    output = tmp_path / "attack"
    ros2 = need_program("ros2")
    launch = _in_workspace(workspace, f"{ros_only_python} {ros2} launch advperc_ros attack.launch.py params:={params} "
                                      f"output:={output} {arguments}", ros_domain)
    got, text = _ended(launch, timeout=TIMEOUT)
    assert got == code, _orchestrator_lines(text)
    if code:
        errors = [line for line in text.splitlines() if "[ERROR]" in line]
        assert len(errors) == 1 and errors[0].endswith("launch argument 'planner' must be ours or external, "
                                                       "got 'elsewhere'"), text[-3000:]
        assert "process started" not in text and not output.exists()
    else:
        assert _report(output)["collision"], _orchestrator_lines(text)


_CLI_REPORTS: dict[str, dict] = {}


def _cli_report(params: Path, output: Path) -> dict:
    """The report `advperc attack params` writes, once per params text on this worker (the Ctrl-C
    tests of `ros2 run` and `ros2 launch` compare with the same one)."""
    key = params.read_text()
    if key not in _CLI_REPORTS:
        cli = subprocess.run([sys.executable, "-m", "advperc_ros.cli", "attack", str(params), "--output", str(output),
                              "--quiet"], cwd=REPO, capture_output=True, text=True, timeout=TIMEOUT)
        assert cli.returncode == 0, cli.stderr
        _CLI_REPORTS[key] = _report(output)
    return _CLI_REPORTS[key]


def _wait_for_rollouts(checkpoint: Path, launch: subprocess.Popen, count: int) -> None:
    deadline = time.monotonic() + TIMEOUT
    while sum(1 for _ in (checkpoint / "rollouts.jsonl").open()) < count if (checkpoint / "rollouts.jsonl").is_file() \
            else True:
        assert launch.poll() is None, launch.communicate()[0][-3000:]
        assert time.monotonic() < deadline, "no rollout checkpointed in time"
        time.sleep(0.2)


@pytest.mark.parametrize("way", ["launch", "run"])
def test_ctrl_c_stops_the_attack_in_seconds_with_130_and_it_resumes_to_the_uninterrupted_report(
        workspace, ros_domain, tmp_path, way):
    """Ctrl-C (SIGINT to the foreground process group, as a terminal sends it) of `ros2 launch` and of
    `ros2 run ... orchestrator`: one line, exit code 130 within seconds, the checkpoint kept; resuming
    (`resume:=true`, `-p resume:=true`) writes the report an uninterrupted run writes."""
    params = _small_params(tmp_path, REPO / "config" / "idm_lane_following.yaml")
    output = tmp_path / "attack"
    if way == "launch":
        command = f"ros2 launch advperc_ros attack.launch.py params:={params} output:={output}"
    else:
        command = f"ros2 run advperc_ros orchestrator --ros-args --params-file {params} -p output:={output}"
    attack = _in_workspace(workspace, command, ros_domain)
    _wait_for_rollouts(tmp_path / ".attack.checkpoint", attack, 2)
    os.killpg(attack.pid, signal.SIGINT)
    stopped = time.monotonic()
    code, log = _ended(attack, timeout=60)
    assert code == 130, log[-3000:]
    assert time.monotonic() - stopped < 30, log[-3000:]
    assert sum("interrupted: " in text for text in log.splitlines()) == 1, log[-3000:]
    assert (tmp_path / ".attack.checkpoint" / "rollouts.jsonl").is_file() and not output.exists()
    resume = (f"{command} resume:=true" if way == "launch" else f"{command} -p resume:=true")
    code, log = _ended(_in_workspace(workspace, resume, ros_domain))
    assert code == 0, log[-3000:]
    progress = [text for text in log.splitlines() if re.search(
        r"\[orchestrator\]: rollout \d+ of about \d+: (no collision|collision|inconclusive .*); (best \S+ [\d.]+|no attack "
        r"yet); \d+ collisions? so far$", text)]  # a line per rollout, those the checkpoint answered too
    assert len(progress) == _report(output)["rollouts"], _orchestrator_lines(log)
    assert _report(output) == _cli_report(params, tmp_path / "cli")


def test_ros2_run_with_the_graph_backend_shows_the_whole_graph_and_gives_the_embedded_report(workspace, ros_domain,
                                                                                             tmp_path):
    """`ros2 run advperc_ros orchestrator ... -p rollout_backend:=graph` starts the five nodes as rclpy
    nodes, named as under the launch file: `ros2 node list` shows all six while it searches."""
    params = _small_params(tmp_path, REPO / "config" / "idm_lane_following.yaml",
                           bag=str(REPO / "bags" / "idm_lane_following"))
    output = tmp_path / "graph"
    run = _in_workspace(workspace, f"ros2 run advperc_ros orchestrator --ros-args --params-file {params} "
                                   f"-p rollout_backend:=graph -p output:={output}", ros_domain)
    try:
        deadline = time.monotonic() + TIMEOUT
        expected = {"/orchestrator", "/scenario_player", "/error_injector", "/tracker", "/planner", "/rule_monitor"}
        listed: set[str] = set()
        while not expected <= listed:
            assert run.poll() is None and time.monotonic() < deadline, (sorted(listed), run.stdout.read()[-3000:])
            nodes = subprocess.run(["ros2", "node", "list"], capture_output=True, text=True, timeout=60,
                                   env=dict(os.environ, ROS_DOMAIN_ID=str(ros_domain)))
            listed = set(nodes.stdout.split())
    except BaseException:
        if run.poll() is None:
            os.killpg(run.pid, 9)
        run.communicate()
        raise
    code, log = _ended(run)
    assert code == 0, log[-3000:]
    embedded = subprocess.run([sys.executable, "-m", "advperc_ros.cli", "attack", str(params), "--output",
                               str(tmp_path / "embedded"), "--quiet"], cwd=REPO, capture_output=True, text=True,
                              timeout=TIMEOUT)
    assert embedded.returncode == 0, embedded.stderr
    assert _report(output) == _report(tmp_path / "embedded")


def test_two_graphs_on_one_domain_never_write_a_no_collision_report(workspace, ros_domain, tmp_path):
    """Two `ros2 run ... rollout_backend:=graph` attacks started together on one ROS domain: their nodes
    would answer each other's rollouts. Each attack either writes the report it writes alone or ends with
    exit code 4 and one line naming the other graph (or its superseded rollouts); at least one sees the other."""
    params = _small_params(tmp_path, REPO / "config" / "idm_lane_following.yaml",
                           bag=str(REPO / "bags" / "idm_lane_following"))
    runs = [_in_workspace(workspace, f"ros2 run advperc_ros orchestrator --ros-args --params-file {params} "
                                     f"-p rollout_backend:=graph -p output:={tmp_path / f'graph{k}'}", ros_domain)
            for k in range(2)]
    ended = [_ended(run) for run in runs]
    embedded = subprocess.run([sys.executable, "-m", "advperc_ros.cli", "attack", str(params), "--output",
                               str(tmp_path / "embedded"), "--quiet"], cwd=REPO, capture_output=True, text=True,
                              timeout=TIMEOUT)
    assert embedded.returncode == 0, embedded.stderr
    refused = 0
    for k, (code, log) in enumerate(ended):
        if code == 0:
            assert _report(tmp_path / f"graph{k}") == _report(tmp_path / "embedded"), log[-3000:]
        else:
            errors = [line for line in log.splitlines() if "[ERROR]" in line and "[orchestrator]" in line]
            assert code == 4 and len(errors) == 1, log[-3000:]
            assert "another graph is running" in errors[0] or "rollouts were inconclusive" in errors[0], errors[0]
            assert not (tmp_path / f"graph{k}").exists()
            refused += "another graph is running" in errors[0]
    assert refused >= 1, [log[-1500:] for _, log in ended]


# ----- a team's own stack: Autoware's messages, a planner on a timer ---------------------------------------

def _attack_beside(workspace: Path, domain: int, tmp_path: Path, node: str, arguments: str) -> tuple[Path, str]:
    """`ros2 launch` of a short attack with `arguments` while a team's node (the command `node`, run in the
    workspace) runs beside it; (the results folder, the node's output), the launch having exited 0."""
    params = _small_params(tmp_path, REPO / "config" / "idm_lane_following.yaml")
    output = tmp_path / "attack"
    team_node = _in_workspace(workspace, node, domain)
    try:
        attack = _in_workspace(workspace, f"ros2 launch advperc_ros attack.launch.py params:={params} output:={output} "
                                          f"{arguments}", domain)
        code, log = _ended(attack, timeout=2 * TIMEOUT)
    finally:
        os.killpg(team_node.pid, signal.SIGINT)
        node_log = _ended(team_node, timeout=60)[1]
    assert code == 0, _orchestrator_lines(log) + node_log[-2000:]
    assert "Traceback" not in node_log, node_log[-3000:]
    return output, node_log


def _example(name: str) -> str:
    """The command that runs `examples/<name>`, a team's node written in Python."""
    return f"python3 {REPO / 'examples' / name}"


def _attack_a_timer_planner_to_a_collision(workspace: Path, domain: int, tmp_path: Path, node: str, name: str,
                                           version: str) -> None:
    """A team's Autoware-style planner on a timer (the command `node`; `name` in the ROS graph, announcing
    `version` on /attack/nodes) attacked with `interface:=autoware drive:=clock` beside a busy process: every
    rollout conclusive, a collision found and reproduced (the drive delivered each frame before its clock),
    the report naming the team's node and its version."""
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])  # a loaded machine delays deliveries
    try:
        output, _ = _attack_beside(workspace, domain, tmp_path, node, "planner:=external interface:=autoware drive:=clock")
    finally:
        busy.kill()
        busy.wait()
    report = _report(output)
    assert report["collision"] is True and report["inconclusive_rollouts"] == 0, report
    assert report["reproduced"] is True  # the timer-driven node, driven by the clock, replays its attack
    assert report["planner"] == "external" and report["planner_node"] == name
    assert report["planner_version"] == version  # announced on /attack/nodes, covered by config_hash
    assert report["params"]["planner"] == "external" and report["params"]["planner_params"] == {}  # not ours: no IDM
    assert f"external ({name} version {version}) planner" in (output / "report.md").read_text()


def test_the_autoware_example_planner_on_a_timer_is_attacked_to_a_collision_through_ros2_launch(
        workspace, ros_domain, tmp_path):
    """examples/autoware_planner.py (PredictedObjects in, a distance-sampled Trajectory out, a 10 Hz
    timer under use_sim_time that plans with whatever it holds; nothing of ours imported) attacked with
    `interface:=autoware drive:=clock` beside a busy process: every rollout conclusive, a collision found
    and reproduced (the drive delivered each frame before its clock), the report naming the team's node.
    test_cpp_planner.py attacks its C++ counterpart the same way."""
    _attack_a_timer_planner_to_a_collision(workspace, ros_domain, tmp_path, _example("autoware_planner.py"),
                                           "/autoware_style_planner", "acc-0.4")


def test_a_team_s_own_tracker_on_vision_msgs_detections_is_attacked_with_our_planner(workspace, ros_domain, tmp_path):
    """examples/vision_tracker.py (Detection3DArray in, our MarkerArray tracks out; nothing of ours
    imported) in place of our tracker with `tracker:=external interface:=vision_msgs`: the errors go
    in at the detector's output and through the team's tracker to our planner; the report names it."""
    output, _ = _attack_beside(workspace, ros_domain, tmp_path, _example("vision_tracker.py"),
                               "tracker:=external interface:=vision_msgs")
    report = _report(output)
    assert report["collision"] is True and report["inconclusive_rollouts"] == 0 and report["reproduced"] is True, report
    assert report["planner"] == "idm" and report["tracker_node"] == "/vision_tracker"
    assert "on the tracks of external tracker /vision_tracker" in (output / "report.md").read_text()
