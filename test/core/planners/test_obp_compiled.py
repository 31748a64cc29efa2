"""ObP's NLP compiled to C (`core.planners.obp.compiled`): rollouts bit for bit those of CasADi's virtual machine
(so an attack is the same with or without a compiler), one compile per NLP kept in the cache, and a machine
without a compiler, or a compile that fails, planning on the virtual machine with a line in the log."""

import logging
import os
import subprocess

import casadi as ca
import numpy as np
import pytest

from advperc_ros.backends.embedded import Stack
from advperc_ros.configs import core_configs
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.planners.obp import compiled
from advperc_ros.params import load_params
from advperc_ros.ros.bag import read_scenario

OPTS = {"print_time": False, "ipopt": {"print_level": 0, "sb": "yes"}}


def toy_solver() -> ca.Function:
    """A two-variable NLP with a parameter: compiles in a second."""
    x, p = ca.SX.sym("x", 2), ca.SX.sym("p")
    return ca.nlpsol("toy", "ipopt", {"x": x, "p": p, "f": (x[0] - p) ** 2 + x[1] ** 2, "g": x[0] * x[1]}, OPTS)


def noisy(shape: tuple[int, int], seed: int) -> PerceptionErrors:
    """Position noise on every object-frame and one frame in ten missed: solves that fail, fallbacks."""
    rng = np.random.default_rng(seed)
    errors = PerceptionErrors.none(*shape)
    errors.dx[:], errors.dy[:] = rng.normal(0.0, 0.7, shape), rng.normal(0.0, 0.7, shape)
    errors.fn[:] = rng.random(shape) < 0.1
    return errors


def oracle_kind(stack: Stack) -> str:
    """SXFunction: the planner's NLP runs on CasADi's virtual machine; External: on its compiled library."""
    return stack.planner.stage2._solver.oracle().class_name()


@pytest.mark.parametrize("name", ["obp_overtake", "obp_right_turn"])
def test_a_compiled_rollout_is_the_virtual_machine_s_bit_for_bit(repo, name, monkeypatch):
    """Perfect perception and noisy perception whose solves fail and fall back, on two scenarios."""
    configs = core_configs(load_params(repo / "config" / f"{name}.yaml"))
    scenario = read_scenario(repo / "bags" / name)
    fast = Stack(scenario, configs)
    monkeypatch.setenv(compiled.SWITCH_ENV, "0")
    slow = Stack(scenario, configs)
    try:
        assert (oracle_kind(fast), oracle_kind(slow)) == ("External", "SXFunction")
        for tensor in (PerceptionErrors.none(*scenario.agents.shape), noisy(scenario.agents.shape, seed=3)):
            a, b = fast.rollout(tensor), slow.rollout(tensor)
            assert np.array_equal(a.ego, b.ego) and np.array_equal(a.distances, b.distances)
            assert (a.planner_failures, a.inconclusive) == (b.planner_failures, b.inconclusive)
        assert a.planner_failures, "the noisy rollout should make solves fail, so that the fallbacks are compared too"
    finally:
        fast.close()
        slow.close()


def test_an_nlp_is_compiled_once_and_then_loaded(tmp_path, monkeypatch):
    monkeypatch.setenv(compiled.CACHE_ENV, str(tmp_path))
    solver = toy_solver()
    first = compiled.compiled_solver("toy", solver, OPTS)
    (library,) = tmp_path.glob("obp-*.so")
    built = library.stat().st_mtime_ns

    def no_compiling(*args, **kwargs):
        raise AssertionError("compiled again")

    monkeypatch.setattr(subprocess, "run", no_compiling)
    again = compiled.compiled_solver("toy", toy_solver(), OPTS)
    assert library.stat().st_mtime_ns == built and oracle_kind_of(again) == "External"
    for f in (solver, first, again):
        assert float(f(x0=[1, 1], p=2, lbg=-1, ubg=1)["x"][0]) == float(solver(x0=[1, 1], p=2, lbg=-1, ubg=1)["x"][0])


def oracle_kind_of(solver: ca.Function) -> str:
    return solver.oracle().class_name()


@pytest.mark.parametrize("broken", ["no compiler", "compile fails", "cache unwritable"])
def test_without_a_library_the_planner_runs_on_the_virtual_machine_and_says_why_once(broken, tmp_path, monkeypatch,
                                                                                      caplog):
    monkeypatch.setattr(compiled, "_said", set())
    monkeypatch.setenv(compiled.CACHE_ENV, str(tmp_path / "cache"))
    if broken == "no compiler":
        monkeypatch.setattr(compiled.shutil, "which", lambda name: None)
    elif broken == "compile fails":
        monkeypatch.setattr(compiled, "nlp_source", lambda solver: "this is not C;\n")
    else:
        (tmp_path / "cache").write_text("a file where the folder should be")
    caplog.set_level(logging.INFO, logger=compiled.__name__)
    solver = toy_solver()
    assert compiled.compiled_solver("toy", solver, OPTS) is solver
    other = toy_solver()
    assert compiled.compiled_solver("toy", other, OPTS) is other  # the same fallback again, not said again
    said = [r.getMessage() for r in caplog.records if "virtual machine" in r.getMessage()]
    reason = {"no compiler": "no C compiler", "compile fails": "the compile failed", "cache unwritable": "cannot be written"}[broken]
    assert len(said) == 1 and reason in said[0], said
    assert not list((tmp_path).rglob("*.so"))


def test_compiling_can_be_turned_off(monkeypatch):
    monkeypatch.setenv(compiled.SWITCH_ENV, "0")
    solver = toy_solver()
    assert compiled.compiled_solver("toy", solver, OPTS) is solver


def test_an_attack_shows_the_planner_s_compile_line(tmp_path, monkeypatch):
    """The compile adds 15 to 30 s to the first attack on a machine: the attack's stderr says why."""
    import io

    from advperc_ros.application import backend_log

    monkeypatch.setenv(compiled.CACHE_ENV, str(tmp_path))
    stream = io.StringIO()
    with backend_log(logging.StreamHandler(stream)):
        compiled.compiled_solver("toy", toy_solver(), OPTS)
    assert stream.getvalue().count("compiling ObP's NLP into") == 1


def test_a_planner_node_loads_a_library_compiled_before_and_never_compiles(tmp_path, monkeypatch, caplog):
    """A node must be up within the graph's start-up time: under `cached` a missing library means the virtual
    machine (said), one an attack compiled is loaded. The planner node sets `cached` unless told otherwise."""
    monkeypatch.setattr(compiled, "_said", set())
    monkeypatch.setenv(compiled.CACHE_ENV, str(tmp_path))
    monkeypatch.setenv(compiled.SWITCH_ENV, compiled.CACHED_ONLY)
    caplog.set_level(logging.INFO, logger=compiled.__name__)
    solver = toy_solver()
    assert compiled.compiled_solver("toy", solver, OPTS) is solver and not list(tmp_path.glob("*.so"))
    assert any("not compiled yet" in r.getMessage() for r in caplog.records)
    monkeypatch.setenv(compiled.SWITCH_ENV, compiled.COMPILE)
    compiled.compiled_solver("toy", toy_solver(), OPTS)  # an attack compiles it
    monkeypatch.setenv(compiled.SWITCH_ENV, compiled.CACHED_ONLY)
    assert oracle_kind_of(compiled.compiled_solver("toy", toy_solver(), OPTS)) == "External"
    import advperc_ros.nodes.planner as node

    monkeypatch.delenv(compiled.SWITCH_ENV)
    with pytest.raises(Exception):  # noqa: B017 (any: the bag does not exist; the policy is set before it is read)
        node._build(None, {"bag": str(tmp_path / "no-bag")}, {}, None)
    assert os.environ[compiled.SWITCH_ENV] == compiled.CACHED_ONLY
