"""The search's own books (core/search/books.py): after every rollout, the rollouts still to come at
most as each stage says from the rows it logged; and the progress bar, which only draws them."""

import itertools
from types import SimpleNamespace

import pytest

from advperc_ros.application import RolloutProgress
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.search.books import Books
from advperc_ros.core.search.config import GuidedConfig, SearchConfig, bound
from advperc_ros.core.search.pipeline import run_search
from advperc_ros.core.search.problem import LogRow, Phase
from advperc_ros.core.search.random_search import RandomSearchConfig
from advperc_ros.core.search.registry import search_method
from test_approach import swerve_problem
from test_search import make_problem
from toy_scenarios import FOLLOW_SPEC, PLATOON_SPEC

RANDOM = RandomSearchConfig(steps=8, proposals=20)
CONFIGS = {"paper": SearchConfig(random=RANDOM, refine_iterations=2, method="paper"),
           "guided": SearchConfig(random=RANDOM, refine_iterations=2, method="guided", guided=GuidedConfig(candidates=40))}


def _estimated(problem, config):
    """(estimate, budget in force) after each rollout of the search of `problem`."""
    seen = []
    run_search(problem, config, on_estimate=lambda estimate: seen.append((estimate, problem.budget)))
    assert [estimate.run for estimate, _ in seen] == list(range(1, len(problem.log) + 1))  # one per rollout
    assert [estimate.row for estimate, _ in seen] == problem.log
    return seen


@pytest.fixture(scope="module", params=sorted(CONFIGS))
def follow(request):
    """A search of each method where the lead's drop collides: (method, problem, estimates)."""
    problem = make_problem(FOLLOW_SPEC)[0]
    return request.param, problem, _estimated(problem, CONFIGS[request.param])


def test_where_a_drop_collides_the_total_shown_from_the_first_rollout_on_only_falls_to_the_count(follow):
    """What can be guaranteed where a drop collides: every stage counts its worst case given its rows,
    drops not rolled out yet with their bisections and the method's share from the first rollout on
    (the paper's refine for the two dropped runs the bound gives it, which this best attack never
    exceeds), so the total never rises (no jump when the first drop collides), never exceeds the
    budget in force and never falls below the rollouts the search goes on to run. The guided method
    spends its share: its last total is the count."""
    method, problem, seen = follow
    count = len(problem.log)
    totals = [estimate.total for estimate, _ in seen]
    assert all(estimate.run <= estimate.total <= budget for estimate, budget in seen)
    assert totals == sorted(totals, reverse=True) and totals[-1] >= count
    assert totals[0] > count  # the first rollout cannot know that the oncoming car's drop does not collide
    if method == "guided":
        assert totals[-1] == count
    labels = {estimate.row.phase: estimate.label for estimate, _ in seen}
    own = search_method(CONFIGS[method]).phases
    assert labels == {**dict.fromkeys(set(labels) - set(own), "heuristic"),
                      **{phase: label.name for phase, label in own.items() if phase in labels}}
    assert own.keys() & labels.keys()  # the method's phases ran, under its names


@pytest.mark.parametrize("spec, method", [(PLATOON_SPEC, "guided"), (None, "paper")], ids=["joint", "approach"])
def test_the_total_rises_only_where_the_joint_drops_or_the_approach_phase_begin(spec, method):
    """They run only when no drop collided, so they count from their first rollout (ahead of time
    they would add their hundred-odd rollouts to every search's estimate): the only rises there
    are; the total never exceeds the budget in force. Platoon: only both cars' drop together
    collides; the swerve scenario (no drop collides): the approach phase finds the collision."""
    problem = make_problem(spec)[0] if spec is not None else swerve_problem()
    seen = _estimated(problem, CONFIGS[method])
    assert all(estimate.run <= estimate.total <= budget for estimate, budget in seen)
    rises = {str(after.row.phase) for (before, _), (after, _) in itertools.pairwise(seen) if after.total > before.total
             and after.row.phase != before.row.phase}
    assert rises == ({"joint"} if spec is not None else {"joint", "approach"})
    assert all(after.total <= before.total for (before, _), (after, _) in itertools.pairwise(seen)
               if after.row.phase == before.row.phase)


@pytest.mark.parametrize("method", sorted(CONFIGS))
def test_the_total_never_exceeds_a_small_budget(method):
    problem = make_problem(FOLLOW_SPEC)[0]
    seen = _estimated(problem, SearchConfig(random=RANDOM, budget=5, method=method))
    assert len(seen) == 5 and [estimate.total for estimate, _ in seen] == [5] * 5


def _booked(method: str, rows: list[tuple[Phase, int, bool]]) -> list[int]:
    """The total after each (phase, agent, collided) row of a search of 3 agents (heuristic 2
    iterations, refine 2) whose best attack has one dropped run, as the books count it."""
    config = SearchConfig(heuristic_iterations=2, refine_iterations=2, method=method)
    errors = PerceptionErrors.none(50, 3)
    errors.fn[10:20, 0] = True
    best = SimpleNamespace(errors=errors, rollout=SimpleNamespace(num_frames=50))
    problem = SimpleNamespace(scenario=SimpleNamespace(agents=SimpleNamespace(shape=(50, 3))),
                              rollouts_allowed=bound(config, 3), best=best)
    totals: list[int] = []
    books = Books(problem, config, search_method(config), lambda estimate: totals.append(estimate.total))
    for rollout, (phase, agent, collided) in enumerate(rows, start=1):
        books.record(LogRow(rollout, phase, agent, 0.0, 0.0, 0.0, 1.0, collided, "", 0, collided, float("nan")))
    return totals


TRUTH = (Phase.GROUND_TRUTH, -1, False)


def _drop(agent: int, collided: bool) -> tuple[Phase, int, bool]:
    return Phase.HEURISTIC_DROP, agent, collided


def _bisections(agents: tuple[int, ...]) -> list[tuple[Phase, int, bool]]:
    """2 iterations of each bound, the agents in lockstep."""
    return [(phase, agent, False) for phase in (Phase.HEURISTIC_START,) * 2 + (Phase.HEURISTIC_END,) * 2
            for agent in agents]


def test_the_books_count_the_guided_share_from_the_first_rollout_and_the_count_from_the_last_drop():
    """Batched: the ground truth and 3 drops (2 collide), then both agents' 4 bisections in lockstep,
    then the rounds' 40 + 2 x 2: 56 rollouts. Until the third drop rolls out it might collide and
    owe 4 bisections: 60 (the old bar showed 4, then 56 from the second drop on)."""
    rows = [TRUTH, _drop(1, True), _drop(2, True), _drop(3, False), *_bisections((1, 2)), *[(Phase.GUIDED, -1, False)] * 44]
    assert _booked("guided", rows) == [60] * 3 + [56] * (len(rows) - 3)


def test_the_books_count_the_paper_s_share_for_two_runs_until_refine_bisects_the_one_there_is():
    """Each agent bisected before the next drop; 39 random steps (one rolled nothing out) and
    refine's 2 of its one dropped run: 53 rollouts, shown as 60 while the last drop might collide,
    then 56 (40 steps, refine's 2 x 2 for the bound's two runs) until refine begins."""
    rows = ([TRUTH, _drop(1, True), *_bisections((1,)), _drop(2, True), *_bisections((2,)), _drop(3, False)]
            + [(Phase.RANDOM, -1, False)] * 39 + [(Phase.REFINE, 1, False)] * 2)
    assert _booked("paper", rows) == [60] * 11 + [56] * 40 + [53] * 2


def test_the_progress_bar_draws_what_the_search_says(follow, capsys):
    """The bar's total, count, phase and best are the estimate's; the log line says the same; `close`
    ends the bar at the count."""
    _, problem, seen = follow
    lines: list[str] = []
    bar = RolloutProgress("follow", enabled=True, say=lines.append, objective="nds_t")
    for estimate, _ in seen:
        bar(estimate)
        assert (bar.bar.total, bar.bar.n) == (estimate.total, estimate.run)
        assert bar.bar.desc == f"follow ({estimate.label}): "  # tqdm ends a description with ": "
        assert bar.bar.postfix == ("best=none yet" if estimate.best is None else f"best={estimate.best:.4f}")
        assert lines[-1].startswith(f"rollout {estimate.run} of about {estimate.total}: ")
        assert lines[-1].endswith(f"; {estimate.collisions} collision{'s' * (estimate.collisions != 1)} so far")
    bar.close()
    assert bar.bar.total == len(problem.log) and len(lines) == len(problem.log)
    assert f"{len(problem.log)}/{len(problem.log)}" in capsys.readouterr().err


def test_the_books_count_the_inconclusive_rollouts_and_the_bar_and_the_log_line_say_so():
    """A stack that fails (a crashed planner, a hung node) shows at once on the console, not only in the report."""
    config = SearchConfig(heuristic_iterations=2, refine_iterations=2)
    problem = SimpleNamespace(scenario=SimpleNamespace(agents=SimpleNamespace(shape=(50, 3))),
                              rollouts_allowed=bound(config, 3), best=None)
    estimates: list = []
    books = Books(problem, config, search_method(config), estimates.append)
    rows = [("", False), ("planner node 'p' is gone", False), ("", True), ("a plan timed out", False)]
    for rollout, (inconclusive, collided) in enumerate(rows, start=1):
        books.record(LogRow(rollout, Phase.HEURISTIC_DROP, 1, 0.0, 0.0, 0.0, 1.0, collided, inconclusive, 0, collided,
                            float("nan")))
    assert [e.inconclusive for e in estimates] == [0, 1, 1, 2] and [e.collisions for e in estimates] == [0, 0, 1, 1]
    lines: list[str] = []
    bar = RolloutProgress("follow", enabled=False, say=lines.append)
    for estimate in estimates:
        bar(estimate)
    assert not lines[0].endswith("inconclusive") and lines[1].endswith("; 0 collisions so far; 1 inconclusive")
    assert lines[-1].startswith("rollout 4 of about ") and lines[-1].endswith("; 1 collision so far; 2 inconclusive")
    assert bar.bar.postfix == "best=none yet, inconclusive=2"
