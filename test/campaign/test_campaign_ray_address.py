"""A campaign's `ray_address`, checked before any work: one line naming the file and the field, exit code 2,
no output folder, within seconds (Ray itself retries an address that does not answer for minutes). Every
address tried is on loopback."""

import socket
import time
from importlib.util import find_spec

import pytest
from test_campaign import write_campaign

from advperc_ros.campaign import spec
from advperc_ros.cli import main
from advperc_ros.exceptions import ParamsError

RAY = find_spec("ray") is not None


def _refusal(tmp_path, repo, capsys, **fields) -> str:
    output = tmp_path / "out"
    campaign = write_campaign(tmp_path / "c.yaml", repo, output, **fields)
    capsys.readouterr()
    assert main(["campaign", str(campaign), "--quiet"]) == 2
    assert not output.exists()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0].removeprefix(f"advperc: error: {campaign}: field 'ray_address' ")


@pytest.mark.parametrize("address", ["garbage", "", "ray://", "127.0.0.1:99999", "127.0.0.1:", ":6379", "a b:1"])
def test_a_ray_address_that_is_no_address_is_refused(tmp_path, repo, capsys, address):
    assert _refusal(tmp_path, repo, capsys, executor="ray", ray_address=address) == (
        f"must be HOST:PORT, auto or ray://HOST:PORT, got {address!r}")


def test_a_ray_address_with_another_executor_is_refused_not_ignored(tmp_path, repo, capsys):
    assert _refusal(tmp_path, repo, capsys, executor="process", ray_address="127.0.0.1:6379") == (
        "is for executor ray, but the executor is process")


def test_a_ray_address_where_nothing_answers_is_refused_in_seconds(tmp_path, repo, capsys):
    with socket.socket() as closed:  # a port of this machine that was free a moment ago: nothing listens on it
        closed.bind(("127.0.0.1", 0))
        port = closed.getsockname()[1]
    start = time.monotonic()
    line = _refusal(tmp_path, repo, capsys, executor="ray", ray_address=f"127.0.0.1:{port}")
    assert time.monotonic() - start < 2 * spec.RAY_REACH_TIMEOUT
    assert line.startswith(f"nothing answers at 127.0.0.1:{port} within 3 s ("), line


def test_auto_without_a_cluster_on_this_machine_is_refused(tmp_path, repo, capsys, monkeypatch):
    monkeypatch.setattr(spec, "RAY_CURRENT_CLUSTER", tmp_path / "no-ray" / "ray_current_cluster")
    assert _refusal(tmp_path, repo, capsys, executor="ray", ray_address="auto").startswith(
        "is auto, but no Ray cluster runs on this machine")


@pytest.mark.skipif(find_spec("grpc") is not None, reason="Ray Client's gRPC is installed here")
def test_a_ray_client_address_without_ray_client_is_refused(tmp_path, repo, capsys):
    assert _refusal(tmp_path, repo, capsys, executor="ray", ray_address="ray://127.0.0.1:10001") == (
        "is 'ray://127.0.0.1:10001', but Ray Client is not installed: pip install 'ray[client]'")


@pytest.mark.parametrize("auto", [False, True])
def test_a_ray_address_that_answers_passes_the_check(tmp_path, repo, monkeypatch, auto):
    """A listening port on loopback (standing in for a head node's): the address is kept as given, and what
    follows is the campaign's own next check (ray installed) or none."""
    with socket.create_server(("127.0.0.1", 0)) as server:
        address = f"127.0.0.1:{server.getsockname()[1]}"
        if auto:
            (tmp_path / "ray_current_cluster").write_text(address + "\n")
            monkeypatch.setattr(spec, "RAY_CURRENT_CLUSTER", tmp_path / "ray_current_cluster")
        given = "auto" if auto else address
        campaign = write_campaign(tmp_path / "c.yaml", repo, tmp_path / "out", executor="ray", ray_address=given)
        if RAY:
            assert spec.load_campaign(campaign).ray_address == given
        else:
            with pytest.raises(ParamsError, match="field 'executor' is ray, but ray is not installed"):
                spec.load_campaign(campaign)
