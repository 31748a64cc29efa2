"""Our NDS against nuscenes-devkit 1.2.0 itself, on committed randomised cases.

The devkit pins numpy<2, so it cannot share this environment: test/fixtures/nds/make_devkit_fixtures.py
runs it from its own venv (see that script's docstring) and stored its answers in devkit_cases.json
(the paper's detector errors: centre and heading offsets, drops) and devkit_cases_kinds.json (the
kinds beyond them: ghosts, size, velocity and heading-flip errors, and all of them mixed).
"""

import json
import math

import numpy as np
import pytest

from conftest import REPO

from advperc_ros.core.boxes import BoxSequence
from advperc_ros.core.metrics.nds import DIST_THRESHOLDS, greedy_match, nds

FIXTURES = REPO / "test" / "fixtures" / "nds"
CASES = json.loads((FIXTURES / "devkit_cases.json").read_text())
KIND_CASES = json.loads((FIXTURES / "devkit_cases_kinds.json").read_text())
GHOST = -1  # agent id of a prediction no agent explains
COLUMNS = ("ids", "x", "y", "yaw", "length", "width", "height", "vx", "vy")


def _boxes(frames: list[list[list[float]]], with_score: bool) -> BoxSequence:
    rows = []
    for boxes in frames:
        arr = np.asarray(boxes, dtype=float).reshape(-1, len(COLUMNS) + with_score)
        frame = {name: arr[:, i] for i, name in enumerate(COLUMNS)}
        frame["ids"] = frame["ids"].astype(np.int64)
        if with_score:
            frame["score"] = arr[:, -1]
        rows.append(frame)
    return BoxSequence.stack(rows)


def case_inputs(case: dict) -> tuple[BoxSequence, BoxSequence, np.ndarray]:
    frames = case["frames"]
    gt = _boxes([f["gt"] for f in frames], with_score=False)
    pred = _boxes([f["pred"] for f in frames], with_score=True)
    ego = np.array([f["ego"] for f in frames], dtype=float)
    return gt, pred, ego


def test_fixtures_cover_the_required_variety():
    assert len(CASES) >= 20
    assert len({round(c["devkit"]["nds"], 6) for c in CASES}) >= 20


def _family(case: dict) -> str:
    return case["name"].split("_")[0]


def _ghosts(case: dict) -> tuple[list[tuple[list[float], list[float]]], list[float]]:
    """The ghosts of a case as (frame ego, row), and the scores of the agents' own detections."""
    ghosts = [(f["ego"], p) for f in case["frames"] for p in f["pred"] if p[0] == GHOST]
    agent_scores = [p[-1] for f in case["frames"] for p in f["pred"] if p[0] != GHOST]
    return ghosts, agent_scores


def _error_kinds(case: dict) -> set[str]:
    """The kinds of detector error a case holds, read off its rows (a prediction's agent id names
    the gt it was made from)."""
    kinds = set()
    for f in case["frames"]:
        gt = {g[0]: g for g in f["gt"]}
        if set(gt) - {p[0] for p in f["pred"]}:
            kinds.add("drop")
        for p in f["pred"]:
            if p[0] == GHOST:
                kinds.add("ghost")
                continue
            g = gt[p[0]]
            heading_error = abs((p[3] - g[3] + math.pi) % (2 * math.pi) - math.pi)
            if p[1:3] != g[1:3]:
                kinds.add("centre")
            if p[4:7] != g[4:7]:
                kinds.add("size")
            if heading_error > 2.5:
                kinds.add("flip")
            elif heading_error > 0.0:
                kinds.add("heading")
            if p[7:9] != g[7:9]:
                kinds.add("velocity of a gt standing still" if g[7] == g[8] == 0.0 else "velocity")
    return kinds


def test_kind_fixtures_cover_the_detector_errors_beyond_the_paper():
    """Each family is there and does what its name says, in the devkit's own numbers: a test that
    passes because a family lost its errors would prove nothing about that kind."""
    names = [c["name"] for c in KIND_CASES]
    assert len(set(names)) == len(names)
    families = {family: [c for c in KIND_CASES if _family(c) == family]
                for family in ("ghost", "size", "vel", "flip", "mixed")}
    assert {family: len(cases) >= 3 for family, cases in families.items()} == dict.fromkeys(families, True)
    assert len(KIND_CASES) == sum(len(cases) for cases in families.values())

    every_kind = {"drop", "ghost", "centre", "size", "flip", "heading", "velocity of a gt standing still"}
    for case in families["mixed"]:
        assert every_kind <= _error_kinds(case), case["name"]
    for family, kind in (("ghost", "ghost"), ("size", "size"), ("flip", "flip")):
        assert all(kind in _error_kinds(case) for case in families[family]), family
    assert all({"velocity", "velocity of a gt standing still"} & _error_kinds(c) for c in families["vel"])

    def most(family, error):
        return max(c["devkit"]["tp_errors"][error] for c in families[family])

    assert most("size", "scale_err") > 0.3
    assert most("vel", "vel_err") > 1.0
    assert most("flip", "orient_err") > 3.0  # close to pi: nearly every detection flipped
    for error, floor in (("scale_err", 0.05), ("vel_err", 0.1), ("orient_err", 1.0)):
        assert most("mixed", error) > floor, error

    # flips of gt headings 0, +-pi and pi/2
    flips = next(c for c in families["flip"] if c["name"] == "flip_exact_yaws")
    gt_yaws = {g[3] for f in flips["frames"] for g in f["gt"]}
    assert {0.0, math.pi, -math.pi, math.pi / 2} <= gt_yaws

    # ghosts ranked above, between and below every detection of an agent
    by_name = {c["name"]: c for c in KIND_CASES}
    ghosts, agents = _ghosts(by_name["ghost_ranked_above_every_detection"])
    assert min(p[-1] for _, p in ghosts) > max(agents)
    ghosts, agents = _ghosts(by_name["ghost_ranked_below_every_detection"])
    assert max(p[-1] for _, p in ghosts) < min(agents)
    ghosts, agents = _ghosts(by_name["ghost_ranked_between_every_detection"])
    assert all(min(agents) < p[-1] < max(agents) for _, p in ghosts)
    # a ghost at exactly 50 m, which the strict < 50 range filter drops
    ghosts, _ = _ghosts(by_name["ghost_at_exactly_50m"])
    assert any(math.hypot(p[1] - ego[0], p[2] - ego[1]) == 50.0 for ego, p in ghosts)
    # only ghosts: with gt all out of range, and with no gt at all
    for name in ("ghost_only_gt_out_of_range", "ghost_only_no_gt"):
        ghosts, agents = _ghosts(by_name[name])
        assert ghosts and not agents, name
    assert not any(f["gt"] for f in by_name["ghost_only_no_gt"]["frames"])

    # ghosts both taking a gt (true positives) and left over (false positives), at every threshold;
    # the matchings are ours, which test_nds_equals_devkit holds to the devkit's numbers
    ghost_matched = {th: [] for th in DIST_THRESHOLDS}
    for case in families["ghost"] + families["mixed"]:
        gt, pred, ego = case_inputs(case)
        result = nds(gt, pred, ego)
        is_ghost = result.pred_in_range & (pred.ids == GHOST)
        for th in DIST_THRESHOLDS:
            ghost_matched[th].extend(result.matchings[th].pred_gt[is_ghost] >= 0)
    assert {th: any(m) and not all(m) for th, m in ghost_matched.items()} == dict.fromkeys(DIST_THRESHOLDS, True)


@pytest.mark.parametrize("case", CASES + KIND_CASES, ids=[c["name"] for c in CASES + KIND_CASES])
def test_nds_equals_devkit(case):
    gt, pred, ego = case_inputs(case)
    ours = nds(gt, pred, ego)
    ref = case["devkit"]
    assert ours.nds == pytest.approx(ref["nds"], abs=1e-9)
    assert ours.mean_ap == pytest.approx(ref["map"], abs=1e-9)
    for th in DIST_THRESHOLDS:
        assert ours.ap[th] == pytest.approx(ref["ap"][f"{th:.1f}"], abs=1e-9), th
    for name, value in ref["tp_errors"].items():
        expected = math.nan if value is None else value
        assert ours.tp_errors[name] == pytest.approx(expected, abs=1e-9, nan_ok=True), name


def devkit_loop(dist, scores, threshold):
    """The devkit's accumulate() matching, frame by frame: predictions by descending (score, index),
    each taking the nearest untaken gt (strict <, so the first of equals) if nearer than the threshold."""
    num_frames, num_pred, num_gt = dist.shape
    out = np.full((num_frames, num_pred), -1)
    for f in range(num_frames):
        taken = set()
        present = [i for i in range(num_pred) if np.isfinite(scores[f, i])]
        for p in sorted(present, key=lambda i: (scores[f, i], i), reverse=True):
            best, best_g = np.inf, None
            for g in range(num_gt):
                if g not in taken and dist[f, p, g] < best:
                    best, best_g = dist[f, p, g], g
            if best_g is not None and best < threshold:
                taken.add(best_g)
                out[f, p] = best_g
    return out


@pytest.mark.parametrize("seed", range(4))
def test_greedy_match_equals_the_devkit_loop(seed):
    """Random frames where predictions compete for gts and distances and scores tie exactly,
    including pairs that may not match (inf) and absent predictions (nan score)."""
    rng = np.random.default_rng(seed)
    num_frames, num_pred, num_gt = 300, rng.integers(1, 7), rng.integers(1, 7)
    dist = rng.choice([0.3, 0.5, 0.7, 1.0, 1.5, 2.0, 3.0, 4.0, 5.0, np.inf], size=(num_frames, num_pred, num_gt))
    dist[::2] = rng.uniform(0.0, 5.0, size=dist[::2].shape)
    scores = rng.choice([0.2, 0.5, 0.9, np.nan], size=(num_frames, num_pred))
    dist[np.isnan(scores)] = np.inf
    got = greedy_match(np.ascontiguousarray(dist.transpose(1, 2, 0)), scores, DIST_THRESHOLDS)
    for i, th in enumerate(DIST_THRESHOLDS):
        np.testing.assert_array_equal(got[i].T, devkit_loop(dist, scores, th), err_msg=f"threshold {th}")
