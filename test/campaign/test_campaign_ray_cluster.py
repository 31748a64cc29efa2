"""`advperc campaign` on a Ray cluster of three nodes on this machine (ray.cluster_utils.Cluster: a head
that runs no cell and two worker nodes, each started in a working directory of its own), whose driver
shares no path with them: the driver runs in a mount namespace of its own, where its campaign folder
(campaign file, params, bag, output) is a tmpfs that no node can see. The campaign completes only if each
cell's inputs reach its worker through Ray and each results folder comes back to be written by the
driver; it gives the process executor's summary.md, with both worker nodes and with one of them removed
under its cell. Ray listens on loopback only. CI runs this in its Ray venv (ADVPERC_REQUIRE_RAY=1),
where it may not skip."""

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from test_campaign import SHORT, need_ray

TASK = b"ray::run_shipped_cell"  # a Ray worker's title while it runs a cell
DRIVER = """
import os, shutil, subprocess, sys
from pathlib import Path
import yaml
private, inputs, kept, address, *argv = sys.argv[1:]
subprocess.run(["mount", "-t", "tmpfs", "advperc-driver", private], check=True)  # seen by this process alone
shutil.copytree(inputs, private, dirs_exist_ok=True)
os.chdir(private)
if address:
    campaign = yaml.safe_load(Path("campaign.yaml").read_text())
    Path("campaign.yaml").write_text(yaml.safe_dump({**campaign, "ray_address": address}))
from advperc_ros.cli import main
code = main(argv)
shutil.copytree(Path(private) / "out", kept)
sys.exit(code)
"""
# a lost node is known in about a second rather than Ray's 15 s (3 s health checks, 5 missed)
FAST_NODE_DEATH = {"health_check_period_ms": 200, "health_check_failure_threshold": 5}
# 127.0.0.1, ::1 and ::ffff:127.0.0.1 as /proc/net/tcp and tcp6 write them
LOOPBACK_LISTEN = ("0100007F:", "00000000000000000000000001000000:", "0000000000000000FFFF00000100007F:")


def need_own_mounts() -> None:
    """The driver's private folder needs a mount namespace (root, or a kernel that lets users have one)."""
    if shutil.which("unshare") and subprocess.run(["unshare", "--mount", "true"], capture_output=True).returncode == 0:
        return
    if os.environ.get("ADVPERC_REQUIRE_RAY") == "1":
        pytest.fail("unshare --mount is refused here, so the cluster test cannot hide the driver's paths")
    pytest.skip("unshare --mount is refused here (not root): the driver's paths cannot be hidden from the nodes")


@pytest.fixture(scope="module")
def inputs(repo, tmp_path_factory) -> Path:
    """The campaign as the driver has it: the two short idm_lane_following cells of test_campaign, the
    params naming a bag folder that no other path holds (not even the package share)."""
    need_ray()
    need_own_mounts()
    folder = tmp_path_factory.mktemp("inputs")
    shutil.copytree(repo / "bags" / "idm_lane_following", folder / "driver_bags" / "idm_lane_following")
    params = yaml.safe_load((repo / "config" / "idm_lane_following.yaml").read_text())
    params["orchestrator"]["ros__parameters"]["bag"] = "driver_bags/idm_lane_following"
    (folder / "idm_lane_following.yaml").write_text(yaml.safe_dump(params))
    (folder / "campaign.yaml").write_text(yaml.safe_dump({
        "name": "small", "output": "out", "scenarios": ["idm_lane_following.yaml"], "objectives": ["nds", "nds_t"],
        "seeds": [0], "overrides": SHORT, "workers": 2}))
    return folder


def start_driver(inputs: Path, kept: Path, executor: str, address: str = "") -> tuple[subprocess.Popen, Path, Path]:
    """The campaign (on the cluster at `address`), run by a driver whose campaign folder only it can see:
    (process, that folder as the nodes see it, where the driver leaves its output)."""
    private = kept.with_name(f"{kept.name}-private")
    private.mkdir()
    process = subprocess.Popen(["unshare", "--mount", "--propagation", "private", sys.executable, "-c", DRIVER,
                                str(private), str(inputs), str(kept), address, "campaign", "campaign.yaml", "--quiet",
                                "--executor", executor], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return process, private, kept


def finish(process: subprocess.Popen, private: Path, kept: Path) -> Path:
    out, err = process.communicate(timeout=600)
    assert process.returncode == 0, err
    assert json.loads(out)["errors"] == 0  # the one line of stdout: Ray's own messages went to stderr
    assert not list(private.iterdir()), "the driver's campaign folder showed through to the nodes"
    return kept


@pytest.fixture(scope="module")
def process_driver(inputs, tmp_path_factory):
    """The process executor's run, started before the cluster so that the two start up side by side."""
    return start_driver(inputs, tmp_path_factory.mktemp("process") / "out", "process")


@pytest.fixture(scope="module")
def cluster(inputs, process_driver, tmp_path_factory):
    # as the campaign's own local Ray: every node on 127.0.0.1 (read when ray is imported, by the nodes too)
    os.environ.update(RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0", RAY_USAGE_STATS_ENABLED="0", RAY_worker_niceness="0")
    from ray.cluster_utils import Cluster

    nodes = tmp_path_factory.mktemp("nodes")
    here = os.getcwd()
    cluster = Cluster()
    try:
        for i, args in enumerate([{"num_cpus": 0, "include_dashboard": False, "_system_config": FAST_NODE_DEATH},
                                  {"num_cpus": 1, "wait": False}, {"num_cpus": 1, "wait": False}]):
            (nodes / f"node{i}").mkdir()
            os.chdir(nodes / f"node{i}")  # the node's raylet, and so its workers, work there
            cluster.add_node(**args)
    finally:
        os.chdir(here)
    cluster.wait_for_nodes()
    yield cluster
    cluster.shutdown()


@pytest.fixture(scope="module")
def by_processes(process_driver, cluster) -> Path:
    return finish(*process_driver)


def _files(output: Path) -> list[str]:
    return sorted(str(path.relative_to(output)) for path in output.rglob("*"))


def _descendants(pid: int) -> set[int]:
    parents = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            parents[int(stat.parent.name)] = int(stat.read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
    found, frontier = set(), {pid}
    while frontier:
        frontier = {child for child, parent in parents.items() if parent in frontier} - found
        found |= frontier
    return found


def _title(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:  # it ended
        return b""


def _listening(pids: set[int]) -> list[str]:
    """The local addresses (as /proc/net/tcp writes them) of the TCP sockets these processes listen on."""
    inodes = set()
    for pid in pids:
        try:
            links = [os.readlink(fd) for fd in Path(f"/proc/{pid}/fd").iterdir()]
        except OSError:
            continue
        inodes |= {link[8:-1] for link in links if link.startswith("socket:[")}
    addresses = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            fields = line.split()
            if fields[3] == "0A" and fields[9] in inodes:  # LISTEN
                addresses.append(fields[1])
    return addresses


def assert_loopback_only() -> None:
    listening = _listening(_descendants(os.getpid()))
    assert listening, "found none of Ray's listening sockets"
    assert [address for address in listening if not address.startswith(LOOPBACK_LISTEN)] == []


def test_a_ray_cluster_without_shared_paths_gives_the_process_executors_table(by_processes, cluster, inputs,
                                                                              tmp_path):
    kept = finish(*start_driver(inputs, tmp_path / "out", "ray", cluster.address))
    assert (kept / "summary.md").read_text() == (by_processes / "summary.md").read_text()
    assert _files(kept) == _files(by_processes)  # every file of every results folder came back
    rows = json.loads((kept / "summary.json").read_text())["cells"]
    assert all(row["worker_peak_rss_mib"] > 50 for row in rows), rows  # each measured where it ran
    assert_loopback_only()


def test_a_ray_cluster_that_loses_a_node_under_a_cell_still_gives_the_table(by_processes, cluster, inputs, tmp_path):
    """The node is killed (no graceful stop) while its worker runs a cell: Ray runs the cell again on the
    node left, and the campaign ends with the same table and no error."""
    node = sorted(cluster.worker_nodes, key=lambda n: n.unique_id)[-1]
    raylet = node.all_processes["raylet"][0].process.pid
    process, private, kept = start_driver(inputs, tmp_path / "out", "ray", cluster.address)
    deadline = time.monotonic() + 300
    while not any(_title(pid).startswith(TASK) for pid in _descendants(raylet)):
        assert process.poll() is None and time.monotonic() < deadline, "no cell ever ran on the node"
        time.sleep(0.1)
    assert_loopback_only()  # the driver and both nodes' workers up
    cluster.remove_node(node, allow_graceful=False)
    finish(process, private, kept)
    assert (kept / "summary.md").read_text() == (by_processes / "summary.md").read_text()
