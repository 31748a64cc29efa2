"""Plots of an attack: best metric against rollouts (the paper's figure 3) and a bird's-eye view."""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Polygon  # noqa: E402

from advperc_ros.attack import AttackOutcome  # noqa: E402
from advperc_ros.core.errors import inject  # noqa: E402
from advperc_ros.core.geometry import box_corners  # noqa: E402
from advperc_ros.core.search.problem import LogRow  # noqa: E402


def metric_vs_rollouts(path: Path, log: list[LogRow], objective: str) -> None:
    """Best adversarial metric after each rollout; heuristic solid, random search dashed, refine dotted."""
    index = np.array([row.rollout for row in log])
    best = np.array([row.best_metric for row in log])
    phases = np.array([{"random": 1, "refine": 2}.get(row.phase, 0) for row in log])
    fig, ax = plt.subplots(figsize=(6, 4))
    styles = {0: ("heuristic", "tab:orange", "-"), 1: ("random search", "tab:cyan", "--"), 2: ("refine", "tab:green", ":")}
    for phase, (label, color, line) in styles.items():
        rows = np.flatnonzero(phases == phase)
        if rows.size:
            start = max(rows[0] - 1, 0)  # join the previous phase's curve
            ax.step(index[start : rows[-1] + 1], best[start : rows[-1] + 1], where="post", color=color,
                    linestyle=line, label=label)
    collided = np.array([row.collided for row in log])
    metric = np.array([row.metric for row in log])
    ax.scatter(index[collided], metric[collided], s=10, color="tab:red", label="adversarial rollout", zorder=3)
    ax.scatter(index[~collided], metric[~collided], s=10, color="0.6", label="no collision", zorder=2)
    ax.set_xlabel("rollouts")
    ax.set_ylabel({"nds": "NDS", "nds_t": "NDS-t"}.get(objective, objective))
    ax.set_title("Best adversarial perception metric")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _boxes(ax, corners: np.ndarray, **style) -> None:
    for box in corners:
        ax.add_patch(Polygon(box, closed=True, **style))


def birds_eye_view(path: Path, outcome: AttackOutcome, seconds_before: float = 3.0) -> None:
    """The last seconds before the collision: truth (black outline), perceived (green), ego (red)."""
    scenario, rollout = outcome.scenario, outcome.recorded
    cfg_len, cfg_wid = outcome.params["ego.length"], outcome.params["ego.width"]
    last = rollout.num_frames - 1
    first = max(0, last - int(round(seconds_before / scenario.dt)))
    frames = np.linspace(first, last, 4).round().astype(int)
    perceived = inject(scenario.agents, outcome.best.errors)
    fig, axes = plt.subplots(1, len(frames), figsize=(4 * len(frames), 4), sharey=True)
    for ax, k in zip(np.atleast_1d(axes), frames):
        ex, ey = rollout.ego[k, 0], rollout.ego[k, 1]
        for lane in scenario.lanes:
            pts = lane.centerline.points
            ax.plot(pts[:, 0], pts[:, 1], color="0.85", linewidth=1, zorder=0)
        ax.plot(rollout.ego[: k + 1, 0], rollout.ego[: k + 1, 1], color="tab:red", linewidth=1)
        _boxes(ax, box_corners(*rollout.ego[k, :3], cfg_len, cfg_wid)[None], facecolor="tab:red", alpha=0.6)
        truth = scenario.agents.frame(k)
        _boxes(ax, box_corners(truth["x"], truth["y"], truth["yaw"], truth["length"], truth["width"]),
               fill=False, edgecolor="black", linewidth=1.2)
        seen = perceived.frame(k)
        _boxes(ax, box_corners(seen["x"], seen["y"], seen["yaw"], seen["length"], seen["width"]),
               facecolor="tab:green", alpha=0.4)
        ax.set_xlim(ex - 15, ex + 35)
        ax.set_ylim(ey - 20, ey + 20)
        ax.set_aspect("equal")
        ax.set_title(f"t = {scenario.times[k]:.1f} s" + (" (collision)" if k == last and rollout.collided else ""))
        ax.grid(alpha=0.2)
    fig.suptitle(f"{scenario.name}: ground truth (outline), perceived (green), ego (red)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def robustness(path: Path, points, objective: str) -> None:
    """Fraction still adversarial and mean metric against perturbation strength (paper figure 5)."""
    strength = np.array([p.strength for p in points])
    fig, (left, right) = plt.subplots(1, 2, figsize=(9, 3.5))
    left.plot(strength, [p.adversarial_fraction for p in points], marker="o", color="tab:red")
    left.set_xlabel("perturbation strength")
    left.set_ylabel("fraction still colliding")
    left.set_ylim(-0.05, 1.05)
    right.plot(strength, [p.mean_metric for p in points], marker="o", color="tab:blue")
    right.set_xlabel("perturbation strength")
    right.set_ylabel({"nds": "NDS", "nds_t": "NDS-t"}.get(objective, objective))
    for ax in (left, right):
        ax.grid(alpha=0.3)
    fig.suptitle("Robustness of the attack to random perturbations")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
