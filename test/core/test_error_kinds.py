"""The error kinds beyond the paper: what each does to a detection, that the paper's tensors stay the
paper's to the bit, that the injector node's per-frame injection is the whole-sequence one float for
float, and that every way a tensor travels (npz, the lockstep message, the checkpoint digest) keeps
it and refuses a broken one naming the field."""

import json
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from advperc_ros.backends.resumed import _digest
from advperc_ros.core.boxes import BOX_FIELDS, BoxSequence
from advperc_ros.core.geometry import wrap_angle
from advperc_ros.core.perception_errors import (
    ERROR_KINDS,
    EXTENDED_KINDS,
    GHOST_LENGTH,
    PAPER_KINDS,
    PerceptionErrors,
    confidence_scores,
    ghost_scores,
    inject,
    inject_frame,
    latency_source,
    parse_error_kinds,
)
from advperc_ros.exceptions import MessageError, ResultsError
from advperc_ros.ros import lockstep
from advperc_ros.ros import messages as msgs


def _truth(frames: int = 12, agents: int = 4, seed: int = 0, gaps: bool = True) -> BoxSequence:
    """Cars moving at different speeds; with `gaps`, some absent for a while (appearing, leaving, coming back)."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames)[:, None] * 0.1
    shape = (frames, agents)
    valid = np.ones(shape, dtype=bool)
    if gaps:
        valid[: frames // 3, 0] = False  # appears late
        valid[frames // 2 : frames // 2 + 2, 1] = False  # leaves and comes back
        valid[-2:, 2] = False  # leaves early
    speed = rng.uniform(0.0, 15.0, agents)
    return BoxSequence(
        ids=np.broadcast_to(np.arange(10, 10 + agents), shape).copy(), valid=valid,
        x=rng.uniform(-30, 30, agents) + speed * t, y=np.broadcast_to(rng.uniform(-10, 10, agents), shape).copy(),
        yaw=np.broadcast_to(rng.uniform(-np.pi, np.pi, agents), shape).copy(), vx=np.broadcast_to(speed, shape).copy(),
        vy=np.zeros(shape), length=np.broadcast_to(rng.uniform(3.5, 5.5, agents), shape).copy(),
        width=np.full(shape, 1.8), height=np.full(shape, 1.5), score=np.full(shape, np.nan))


def _random_errors(shape, rng, kinds=ERROR_KINDS, ghosts=3) -> PerceptionErrors:
    e = PerceptionErrors.none(*shape, kinds, ghosts)
    e.dx[:], e.dy[:], e.dyaw[:] = rng.normal(0, 2, shape), rng.normal(0, 2, shape), rng.normal(0, 0.5, shape)
    e.fn[:] = rng.random(shape) < 0.2
    for name, array in e.arrays().items():
        if name in ("dx", "dy", "dyaw", "fn"):
            continue
        if array.dtype == bool:
            array[:] = rng.random(array.shape) < 0.4
        elif name == "latency":
            array[:] = rng.integers(0, 5, array.shape)
        elif name.endswith("_scale"):
            array[:] = rng.uniform(0.5, 2.0, array.shape)
        else:
            array[:] = rng.normal(0, 5, array.shape)
    return e


def _paper_inject(truth: BoxSequence, errors: PerceptionErrors) -> BoxSequence:
    """I(y, e) as the paper's tool computed it before any other kind existed (the reference `paper` keeps)."""
    return replace(truth, valid=truth.valid & ~errors.fn, x=truth.x + errors.dx, y=truth.y + errors.dy,
                   yaw=wrap_angle(truth.yaw + errors.dyaw), score=confidence_scores(*truth.shape))


def _same(a: BoxSequence, b: BoxSequence) -> None:
    for name in ("ids", "valid", *BOX_FIELDS):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_parse_error_kinds():
    assert parse_error_kinds("paper") == PAPER_KINDS == ("position", "yaw", "drop")
    assert parse_error_kinds("all") == ERROR_KINDS
    assert parse_error_kinds(" ghost,latency ") == (*PAPER_KINDS, "latency", "ghost")  # the one order, not the user's
    assert parse_error_kinds("drop") == PAPER_KINDS  # the paper's are always on: the search finds failures with them
    for bad in ("", "drop,", "ghosts", "paper,ghost"):
        with pytest.raises(ValueError, match="unknown error kind"):
            parse_error_kinds(bad)


def test_a_paper_tensor_is_the_papers_to_the_bit():
    truth = _truth()
    errors = _random_errors(truth.shape, np.random.default_rng(1), PAPER_KINDS)
    assert errors.kinds == PAPER_KINDS and list(errors.arrays()) == ["dx", "dy", "dyaw", "fn"]
    _same(inject(truth, errors), _paper_inject(truth, errors))
    legacy = __import__("hashlib").sha256(b"".join(np.ascontiguousarray(a).tobytes() for a in
                                                  (errors.dx, errors.dy, errors.dyaw, errors.fn))).hexdigest()
    assert _digest(errors) == legacy  # checkpoints written before the extended kinds still resume


def test_each_kind_changes_only_what_it_names():
    truth = _truth(gaps=False)
    base = PerceptionErrors.none(*truth.shape, ERROR_KINDS, 2)
    _same(inject(truth, base).select(slice(None)), replace(_paper_inject(truth, base), **{
        f: np.hstack([getattr(_paper_inject(truth, base), f), getattr(inject(truth, base), f)[:, 4:]])
        for f in ("ids", "valid", *BOX_FIELDS)}))  # neutral arrays: the truth, and two ghost slots off
    assert not inject(truth, base).valid[:, 4:].any()

    e = base.copy()
    e.dvx[3, 1], e.dvy[3, 1] = 2.0, -1.0
    seen = inject(truth, e)
    assert seen.vx[3, 1] == truth.vx[3, 1] + 2.0 and seen.vy[3, 1] == -1.0
    assert np.count_nonzero(seen.vx[:, :4] != truth.vx) == 1

    e = base.copy()
    e.length_scale[2, 0], e.width_scale[2, 0] = 0.5, 2.0
    seen = inject(truth, e)
    assert seen.length[2, 0] == truth.length[2, 0] * 0.5 and seen.width[2, 0] == 3.6 and seen.x[2, 0] == truth.x[2, 0]

    e = base.copy()
    e.flip[5, 2] = True
    seen = inject(truth, e)
    assert abs(abs(wrap_angle(seen.yaw[5, 2] - truth.yaw[5, 2])) - np.pi) < 1e-12
    assert seen.x[5, 2] == truth.x[5, 2] and seen.vx[5, 2] == truth.vx[5, 2]  # a flip turns the box, not the car

    e = base.copy()
    e.latency[6, 3] = 2
    seen = inject(truth, e)
    for name in ("x", "y", "yaw", "vx", "length"):  # as the car was two frames ago, confidence of its cell now
        assert getattr(seen, name)[6, 3] == getattr(truth, name)[4, 3]
    assert seen.score[6, 3] == confidence_scores(*truth.shape)[6, 3] and seen.valid[6, 3]


def test_latency_never_reaches_before_the_cars_present_appearance():
    valid = np.array([[0, 1], [1, 1], [1, 0], [1, 1], [1, 1], [1, 1]], dtype=bool)
    latency = np.full(valid.shape, 3)
    source = latency_source(valid, latency, slice(None))
    assert source[:, 0].tolist() == [0, 1, 1, 1, 1, 2]  # frame 0 absent: never shown as then
    assert source[:, 1].tolist() == [0, 0, 2, 3, 3, 3]  # gone at 2 (its own frame), back at 3: from 3 on
    assert latency_source(valid, latency, slice(4, 5)).tolist() == [source[4].tolist()]
    assert (latency_source(valid, np.zeros_like(latency), slice(None)) == np.arange(6)[:, None]).all()


def test_ghosts_are_cars_no_agent_explains_ranked_in_one_band():
    truth = _truth()
    e = PerceptionErrors.none(*truth.shape, ("ghost",), 3)
    e.ghost_on[4, 1] = e.ghost_on[7, 0] = True
    e.ghost_x[4, 1], e.ghost_y[4, 1], e.ghost_yaw[4, 1], e.ghost_vx[4, 1] = 12.0, -3.0, 4.0, 7.0
    seen = inject(truth, e)
    assert seen.shape == (truth.shape[0], truth.shape[1] + 3)
    assert seen.valid[:, 4:].sum() == 2 and seen.ids[4, 5] == -2 and seen.ids[7, 4] == -1
    assert (seen.x[4, 5], seen.y[4, 5], seen.vx[4, 5], seen.length[4, 5]) == (12.0, -3.0, 7.0, GHOST_LENGTH)
    assert seen.yaw[4, 5] == wrap_angle(4.0)
    real = confidence_scores(*truth.shape)
    band = ghost_scores(*truth.shape, 3)
    assert len(np.unique(np.concatenate([real.ravel(), band.ravel()]))) == real.size + band.size  # no ties
    below = (real < band.min()).sum()
    assert below == (real < band.max()).sum() == round(real.size / 2)  # all in one gap between real scores
    assert np.array_equal(seen.score[:, 4:], band)  # whatever the attack switches on


@settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))
@given(seed=st.integers(0, 2**32 - 1), kinds=st.sets(st.sampled_from(list(EXTENDED_KINDS))))
def test_the_injector_nodes_frames_are_the_whole_sequences(seed, kinds):
    """The node sees frame k with only frames up to k known (later rows of its history left invalid
    and arbitrary): its boxes are `inject`'s of that frame, float for float, in the same order."""
    rng = np.random.default_rng(seed)
    truth = _truth(seed=seed)
    errors = _random_errors(truth.shape, rng, PAPER_KINDS + tuple(sorted(kinds)))
    whole = inject(truth, errors)
    for k in range(truth.shape[0]):
        history = replace(truth, valid=truth.valid.copy(), x=truth.x.copy())
        history.valid[k + 1 :] = False
        history.x[k + 1 :] = np.nan  # frames not yet arrived are never read
        got, want = inject_frame(history, k, errors), whole.frame(k)
        assert got.keys() == want.keys()
        for name in want:
            np.testing.assert_array_equal(got[name], want[name], err_msg=f"frame {k}, {name}")


def test_a_tensor_of_every_kind_survives_every_way_it_travels(tmp_path):
    errors = _random_errors((6, 3), np.random.default_rng(3))
    assert PerceptionErrors.from_arrays(errors.arrays()).equals(errors)
    back = lockstep.parse_errors(lockstep.errors_message(
        lockstep.RolloutErrors(7, errors, np.arange(3), np.arange(6) * 100)))
    assert back.errors.equals(errors) and back.errors.kinds == ERROR_KINDS
    np.savez(tmp_path / "e.npz", **errors.arrays())
    from advperc_ros.results.folder import load_errors
    assert load_errors(tmp_path / "e.npz").equals(errors)
    assert _digest(errors) != _digest(errors.with_arrays(latency=None, ghost_on=None, ghost_x=None, ghost_y=None,
                                                         ghost_yaw=None, ghost_vx=None, ghost_vy=None))


@pytest.mark.parametrize(("change", "words"), [
    ({"latency": -np.ones((6, 3), dtype=np.int64)}, "field 'latency' must be at least 0"),
    ({"latency": np.ones((6, 3))}, "field 'latency' must hold whole numbers"),
    ({"length_scale": np.zeros((6, 3))}, "field 'length_scale' must be above 0"),
    ({"dvx": np.full((6, 3), np.nan)}, "field 'dvx' must hold finite numbers"),
    ({"flip": np.zeros((6, 3))}, "field 'flip' must hold booleans"),
    ({"ghost_x": np.zeros((5, 2))}, "field 'ghost_x' must be a frames x ghost slots array"),
    ({"dvy": None}, "field 'dvy' is missing"),
    ({"speed": np.zeros((6, 3))}, "field 'speed' is no part of an error tensor"),
])
def test_a_broken_tensor_is_refused_naming_its_field(change, words, tmp_path):
    arrays = {**_random_errors((6, 3), np.random.default_rng(4), ghosts=2).arrays(), **change}
    arrays = {name: array for name, array in arrays.items() if array is not None}
    with pytest.raises(ValueError, match=words):
        PerceptionErrors.from_arrays(arrays)
    np.savez(tmp_path / "e.npz", **arrays)
    from advperc_ros.results.folder import load_errors
    with pytest.raises(ResultsError, match=words) as caught:
        load_errors(tmp_path / "e.npz")
    assert str(caught.value).startswith(str(tmp_path / "e.npz"))
    if "speed" in change:  # a message's other fields are the sender's business (as its rollout number is)
        return
    document = {"rollout": 1, "agent_ids": [1, 2, 3], "stamps_ns": list(range(6)),
                **{name: np.asarray(a).tolist() for name, a in arrays.items()}}
    with pytest.raises(MessageError, match="/attack/errors: field"):
        lockstep.parse_errors(msgs.string(json.dumps(document)))
