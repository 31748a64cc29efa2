"""The pictures of an attack show what they claim: the ego and the car it hits inside every bird's-eye
panel, whatever the road's heading; an animation of the whole rollout; a search that found nothing
plotted as such."""

import dataclasses
import re

import matplotlib.pyplot as plt
import numpy as np
import pytest
from PIL import Image
from test_cli import write_params
from toy_scenarios import FOLLOW_SPEC, RUNAWAY_LEAD_SPEC, rotated

from advperc_ros.application import run_attack
from advperc_ros.core.geometry import box_corners
from advperc_ros.core.scenario_spec import build_scenario
from advperc_ros.params import load_params
from advperc_ros.results import plots
from advperc_ros.ros.bag import read_scenario


def _attack(scenario, repo, base):
    """A small search on `scenario` (the params' bag is not read: the scenario is given)."""
    return run_attack(scenario, load_params(write_params(base / "params.yaml", repo)), progress=False)


@pytest.fixture(scope="module", params=["bundled", "diagonal"])
def outcome(request, repo, tmp_path_factory):
    """An attack that collides on idm_lane_following (road along x) and on a road turned by 40 degrees."""
    if request.param == "bundled":
        scenario = read_scenario(repo / "bags" / "idm_lane_following")
    else:
        scenario = build_scenario(rotated(FOLLOW_SPEC, 40.0))
    result = _attack(scenario, repo, tmp_path_factory.mktemp(request.param))
    assert result.best is not None and result.recorded.collided
    return result


def _inside(points: np.ndarray, ax) -> bool:
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    return bool(np.all((points[:, 0] >= x0) & (points[:, 0] <= x1) & (points[:, 1] >= y0) & (points[:, 1] <= y1)))


def test_every_bev_panel_holds_the_ego_and_the_collision_agent(outcome):
    scenario, rollout = outcome.scenario, outcome.recorded
    agents = scenario.agents
    _, slot = rollout.closest_approach()
    ego_size = (outcome.params.ego.length, outcome.params.ego.width)
    fig = plots.bev_figure(outcome)
    panels = [ax for ax in fig.axes if ax.get_title()]
    assert len(panels) == 4
    for ax in panels:
        k = int(round(float(re.search(r"t = ([\d.]+) s", ax.get_title()).group(1)) / scenario.dt))
        assert ax.get_aspect() == 1.0
        assert _inside(box_corners(*rollout.ego[k, :3], *ego_size), ax), ax.get_title()
        assert agents.valid[k, slot]
        hit = box_corners(agents.x[k, slot], agents.y[k, slot], agents.yaw[k, slot], agents.length[k, slot],
                          agents.width[k, slot])
        assert _inside(hit, ax), ax.get_title()
    assert "collision" in panels[-1].get_title()
    plt.close(fig)


def test_a_collision_is_marked_as_the_collision_it_is(outcome):
    """The collision rule's first violation is the closest approach, the frame the drive ends at: the plots'
    collision look marks it (the last panel's "(collision)"), nothing is drawn over it."""
    mark = plots.violation_mark(outcome)
    last = outcome.recorded.num_frames - 1
    assert mark is not None and mark.rule == "collision" and mark.shown_as_collision
    assert mark.frame == outcome.recorded.closest_approach()[0] == last == outcome.violation_frame
    assert mark.label == (f"collision violated at t = {outcome.scenario.times[last]:.1f} s "
                          f"(r = {outcome.recorded.min_signed_distance:.2f} m)")
    fig = plots.bev_figure(outcome)
    assert "violat" not in fig.get_suptitle() and not any("violated" in ax.get_title() for ax in fig.axes)
    plt.close(fig)


def test_a_ghost_detection_beside_the_ego_is_drawn_inside_every_panel(outcome, tmp_path):
    """A ghost (a perceived car no agent explains, one more slot than the agents) 6 m ahead of the ego in
    every frame: each bird's-eye panel frames it, and the animation draws it."""
    rollout = outcome.recorded
    errors = outcome.best.errors.with_kind("ghost", ghosts=2)
    frames = errors.shape[0]
    ego = rollout.ego[np.minimum(np.arange(frames), rollout.num_frames - 1)]
    on = np.zeros((frames, 2), dtype=bool)
    on[:, 1] = True
    ahead = {"ghost_x": ego[:, 0] + 6.0 * np.cos(ego[:, 2]), "ghost_y": ego[:, 1] + 6.0 * np.sin(ego[:, 2])}
    ghosted = errors.with_arrays(ghost_on=on, ghost_yaw=np.repeat(ego[:, 2:3], 2, axis=1),
                                 **{name: np.repeat(values[:, None], 2, axis=1) for name, values in ahead.items()})
    shown = dataclasses.replace(outcome, best=dataclasses.replace(outcome.best, errors=ghosted))
    fig = plots.bev_figure(shown)
    for ax in [ax for ax in fig.axes if ax.get_title()]:
        k = int(round(float(re.search(r"t = ([\d.]+) s", ax.get_title()).group(1)) / outcome.scenario.dt))
        assert _inside(box_corners(ahead["ghost_x"][k], ahead["ghost_y"][k], ego[k, 2], 4.5, 1.8), ax), ax.get_title()
    plt.close(fig)
    plots.attack_animation(tmp_path / "attack.gif", shown)


def test_the_animation_shows_the_whole_rollout_up_to_the_collision(outcome, tmp_path):
    frames = plots.animation_frames(outcome)
    last = outcome.recorded.num_frames - 1
    step = frames[1] - frames[0]
    assert frames[-1] == last and frames[0] < step and np.all(np.diff(frames) == step)
    assert len(frames) <= plots.GIF_MAX_FRAMES
    plots.attack_animation(tmp_path / "attack.gif", outcome)
    with Image.open(tmp_path / "attack.gif") as gif:
        assert gif.format == "GIF" and gif.n_frames == len(frames)
        gif.seek(gif.n_frames - 1)
        colours = np.unique(np.asarray(gif.convert("RGB")).reshape(-1, 3), axis=0)
        assert len(colours) > 5  # a drawn scene, not a blank frame


def _drawn_labels(ax) -> set[str]:
    """Labels of the artists that hold data."""
    labels = {line.get_label() for line in ax.get_lines() if len(line.get_xdata())}
    return labels | {c.get_label() for c in ax.collections if len(c.get_offsets())}


def test_metric_plot_of_an_attack_has_a_legend_only_for_what_it_draws(outcome):
    fig = plots.metric_figure(outcome.log, "nds_t")
    ax = fig.axes[0]
    assert ax.get_title() == "Best adversarial perception metric"
    legend = {text.get_text() for text in ax.get_legend().get_texts()}
    assert "heuristic" in legend and legend <= _drawn_labels(ax)
    plt.close(fig)


def test_metric_plot_of_a_search_without_collision_says_so(repo, tmp_path):
    null = _attack(build_scenario(RUNAWAY_LEAD_SPEC), repo, tmp_path)
    assert null.best is None and not any(row.collided for row in null.log)
    heuristic = [row for row in null.log if row.phase != "approach"]  # ground truth, drops, the blind rollout
    fig = plots.metric_figure(heuristic, "nds_t")
    ax = fig.axes[0]
    assert "adversarial" not in ax.get_title().lower() and "No collision found" in ax.get_title()
    legend = {text.get_text() for text in ax.get_legend().get_texts()}
    assert legend <= _drawn_labels(ax) and not legend & {"heuristic", "random search", "refine", "adversarial rollout"}
    names = {text.get_text().split(":")[0] for text in ax.texts}
    assert names == {"no drop", "agent 1 dropped", "agent 7 dropped", "joint drop"}  # every rollout says what it hid
    plt.close(fig)
    # with the approach phase's rollouts too there are many: the nearest one is named
    fig = plots.metric_figure(null.log, "nds_t")
    assert len(fig.axes[0].texts) == 1
    plt.close(fig)
