"""Plots of an attack: best metric against rollouts (the paper's figure 3), a bird's-eye view of the
last seconds and an animation of the whole attack rollout. Headless (Agg)."""

from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.artist import Artist
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator
from PIL import Image

from advperc_ros.core.geometry import box_corners
from advperc_ros.core.perception_errors import inject
from advperc_ros.core.rollout import RolloutResult, true_agents
from advperc_ros.core.rules.registry import rule_class
from advperc_ros.core.rules.verdict import CONTACT_RULES
from advperc_ros.core.search.books import SHARED_PHASES
from advperc_ros.core.search.heuristic import LABEL as HEURISTIC
from advperc_ros.core.search.problem import LogRow, Phase, PhaseLabel
from advperc_ros.core.search.registry import every_phase
from advperc_ros.results.outcome import AttackOutcome

METRIC_NAMES = {"nds": "NDS", "nds_t": "NDS-t", "pem_ll": "PEM LL"}
# one style per layer, shared by the bird's-eye view and the animation (the bag's colours where it has them)
BOX_STYLES: dict[str, dict[str, Any]] = {  # matplotlib keyword arguments
    "truth": dict(facecolor="none", edgecolor="black", linewidth=1.2, label="ground truth"),
    "perceived": dict(facecolor="tab:green", edgecolor="none", alpha=0.45, label="perceived"),
    "tracks": dict(facecolor="none", edgecolor="tab:blue", linewidth=1.0, linestyle="--", label="tracks"),
    "ego": dict(facecolor="tab:red", edgecolor="none", alpha=0.7, label="ego"),
}
PLAN_STYLE: dict[str, Any] = dict(color="tab:orange", linewidth=1.5, label="plan")
# the ego's box at the attacked rule's first violation, when the collision's own look does not mark it
VIOLATION_STYLE: dict[str, Any] = dict(facecolor="none", edgecolor="tab:purple", linewidth=2.0,
                                       label="ego at the violation")
LANE_STYLE: dict[str, Any] = dict(color="0.8", linewidth=1.0, zorder=0)
NEAR = 10.0  # m: agents closer than this to the ego are kept inside the bird's-eye view
LOOK_AHEAD = 2.0  # s: the view reaches where the ego will be this much later, so it follows its heading
MIN_HALF_WIDTH = 12.0  # m
MARGIN = 3.0  # m around everything a panel must show
GIF_PERIOD = 0.2  # s of scenario between animation frames (5 frames per second of scenario)
GIF_MAX_FRAMES = 80  # a longer scenario plays faster rather than costing more
GIF_WINDOW = ((-15.0, 45.0), (-15.0, 15.0))  # m, ego frame: x ahead, y left


def metric_figure(log: list[LogRow], objective: str, phases: Mapping[Phase, PhaseLabel] | None = None) -> Figure:
    """The paper's figure 3 when the search found a collision, else why it did not (closest approaches).
    `phases`: the search method's phases and how to show them (`SearchMethod.phases`; default: every
    registered method's)."""
    fig, ax = plt.subplots(figsize=(6, 4))
    index = np.array([row.rollout for row in log])
    collided = np.array([row.collided for row in log], dtype=bool)
    if collided.any():
        _best_metric(ax, log, index, collided, objective, every_phase() if phases is None else phases)
    else:
        _closest_approaches(ax, log, index)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    return fig


def _best_metric(ax, log: list[LogRow], index: np.ndarray, collided: np.ndarray, objective: str,
                 phases: Mapping[Phase, PhaseLabel]) -> None:
    """Best adversarial metric after each rollout, each stretch of rollouts shown as its phase's stage
    shows it (`PhaseLabel`): the heuristic's solid, the approach phase's (when no drop collided) solid
    brown; the paper's random search dashed, refine dotted, guided rounds dash-dotted (refine may run
    between two stretches of rounds)."""
    best = np.array([row.best_metric for row in log])
    styles = {str(phase): label for phase, label in {**SHARED_PHASES, **phases}.items()}  # a log read back has str phases
    kinds = [styles.get(str(row.phase), HEURISTIC) for row in log]
    starts = [i for i, kind in enumerate(kinds) if i == 0 or kind != kinds[i - 1]]  # each stretch of one phase
    labelled = set()
    for start, end in zip(starts, [*starts[1:], len(log)]):
        label = kinds[start]
        first = max(start - 1, 0)  # join the previous stretch's curve
        ax.step(index[first:end], best[first:end], where="post", color=label.color, linestyle=label.line,
                label=None if label.name in labelled else label.name)
        labelled.add(label.name)
    metric = np.array([row.metric for row in log])
    ax.scatter(index[collided], metric[collided], s=10, color="tab:red", label="adversarial rollout", zorder=3)
    if (~collided).any():
        ax.scatter(index[~collided], metric[~collided], s=10, color="0.6", label="no collision", zorder=2)
    ax.set_xlabel("rollouts")
    ax.set_ylabel(METRIC_NAMES.get(objective, objective))
    ax.set_title("Best adversarial perception metric")


def _closest_approaches(ax, log: list[LogRow], index: np.ndarray) -> None:
    """Each rollout's closest approach (perfect perception, then one agent's whole track dropped per
    rollout): how far the search stayed from a collision. All rollouts, when few, or the nearest name their drop."""
    distance = np.array([row.min_signed_distance for row in log])
    conclusive = np.isfinite(distance) & np.array([not row.inconclusive for row in log], dtype=bool)
    ax.scatter(index[conclusive], distance[conclusive], s=14, color="0.4", label="rollout (no collision)", zorder=3)
    if (~conclusive).any():
        ax.scatter(index[~conclusive], np.zeros((~conclusive).sum()), marker="x", color="tab:purple",
                   label="inconclusive", zorder=3)
    ax.axhline(0.0, color="tab:red", linestyle="--", linewidth=1, label="collision (signed distance < 0)")
    rows = np.flatnonzero(conclusive)
    few = rows.size <= 12
    for i in rows if few else rows[np.argsort(distance[rows], kind="stable")[:1]]:
        row = log[i]
        what = {"approach": "approach", "joint": "joint drop"}.get(row.phase, "no drop" if row.agent < 0
                                                                      else f"agent {row.agent} dropped")
        ax.annotate(f"{what}: {row.min_signed_distance:.2f} m", (row.rollout, row.min_signed_distance),
                    textcoords="offset points", xytext=(0, -12), ha="center" if few else "left", fontsize=7)
    if few:
        ax.margins(x=0.15)  # room for the labels of the first and last rollouts
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("rollouts")
    ax.set_ylabel("closest approach of the ego (m)")
    ax.set_ylim(bottom=min(-0.5, ax.get_ylim()[0]))
    ax.set_title(f"No collision found in {len(log)} rollouts")


def metric_vs_rollouts(path: Path, log: list[LogRow], objective: str,
                       phases: Mapping[Phase, PhaseLabel] | None = None) -> None:
    _save(metric_figure(log, objective, phases), path, dpi=120)


def _save(fig: Figure, path: Path, dpi: int) -> None:
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def _recorded(outcome: AttackOutcome) -> RolloutResult:
    """The recorded attack rollout the bird's-eye view and the animation draw (an outcome with a best attack has one)."""
    return outcome.attack_rollout


@dataclass(frozen=True)
class ViolationMark:
    """The attacked rule's first violation on the attack's rollout, where the bird's-eye view and the animation
    mark it, so a reviewer sees when a rule other than the collision broke, not only where the drive ended."""

    rule: str
    frame: int
    time: float  # s
    unit: str
    per_frame: np.ndarray = field(repr=False, compare=False)  # (K,) r at every frame of the attack's rollout
    # a contact rule broken at the closest approach: the collision, which the plots' own look marks already
    shown_as_collision: bool = False

    @property
    def value(self) -> float:
        """r at the violating frame."""
        return float(self.per_frame[self.frame])

    @property
    def label(self) -> str:
        return f"{self.rule} violated at t = {self.time:.1f} s (r = {self.value:.2f} {self.unit})"


def violation_mark(outcome: AttackOutcome) -> ViolationMark | None:
    """Where the attacked rule first breaks on the attack's rollout; None where the rulebook did not judge it (an
    outcome without a ground-truth rollout, as a replay's) or it is not broken."""
    judged = outcome.attacked_rule_value
    if judged is None or judged.first_violation is None:
        return None
    rule, frame = outcome.attacked_rule, judged.first_violation
    return ViolationMark(rule, frame, float(outcome.scenario.times[frame]), rule_class(rule).unit, judged.per_frame,
                         rule in CONTACT_RULES and frame == outcome.attack_rollout.closest_approach()[0])


def _corners(boxes: dict[str, np.ndarray]) -> np.ndarray:
    return box_corners(boxes["x"], boxes["y"], boxes["yaw"], boxes["length"], boxes["width"]).reshape(-1, 4, 2)


class _Scene:
    """What is drawn at a frame of the recorded attack rollout, in map coordinates."""

    def __init__(self, outcome: AttackOutcome) -> None:
        rollout = _recorded(outcome)
        if outcome.best is None or rollout.tracks is None or rollout.plans is None:
            raise ValueError(f"{outcome.scenario.name}: the attack rollout was recorded without its tracks and plans")
        self.outcome = outcome
        self.rollout = rollout
        self.tracks, self.plans = rollout.tracks, rollout.plans
        self.truth = true_agents(rollout, outcome.scenario)  # under reactive traffic the agents as they drove
        self.perceived = inject(self.truth, outcome.best.errors)
        self.ego_size = (outcome.params.ego.length, outcome.params.ego.width)
        mark = violation_mark(outcome)
        # the attacked rule's violation, where the collision's look (the drive ending at a contact) does not show it
        self.mark = None if mark is None or mark.shown_as_collision else mark
        self.ended_in_contact = bool(rollout.rule[-1] < 0.0)
        # the agent every view keeps in sight: the closest approach's, unless another rule's violation is marked
        self.watched = -1 if self.mark is not None else rollout.closest_approach()[1]

    def boxes(self, k: int) -> dict[str, np.ndarray]:
        """Corners (n, 4, 2) per layer of BOX_STYLES; no tracks at the collision frame (nothing was planned)."""
        tracks = self.tracks
        x, y, yaw = self.rollout.ego[k, :3]
        return {
            "truth": _corners(self.truth.frame(k)),
            "perceived": _corners(self.perceived.frame(k)),
            "tracks": _corners(tracks[k]) if k < len(tracks) else np.zeros((0, 4, 2)),
            "ego": box_corners(x, y, yaw, *self.ego_size)[None],
        }

    def plan(self, k: int) -> np.ndarray:
        plans = self.plans
        return np.column_stack([plans[k].x, plans[k].y]) if k < len(plans) else np.zeros((0, 2))

    def involved(self, k: int) -> np.ndarray:
        """Points a view of frame k must contain: the ego, where it heads, the collision agent (true and
        perceived; `watched`), every agent within NEAR of the ego and every ghost detection centred within NEAR."""
        agents, perceived, ego = self.truth, self.perceived, self.rollout.ego[k]
        slots = (self.rollout.distances[k] < NEAR) | (np.arange(agents.shape[1]) == self.watched)
        ghosts = np.hypot(perceived.x[k, len(slots):] - ego[0], perceived.y[k, len(slots):] - ego[1]) < NEAR
        x, y, yaw = ego[:3]
        points = [box_corners(x, y, yaw, *self.ego_size),
                  ego[None, :2] + LOOK_AHEAD * max(ego[3], 1.0) * np.array([[np.cos(ego[2]), np.sin(ego[2])]])]
        for boxes, shown in ((agents, slots), (perceived, np.concatenate([slots, ghosts]))):
            keep = shown & boxes.valid[k]
            points.append(box_corners(boxes.x[k, keep], boxes.y[k, keep], boxes.yaw[k, keep],
                                      boxes.length[k, keep], boxes.width[k, keep]).reshape(-1, 2))
        return np.concatenate(points)


def _legend(fig: Figure, marked: bool = False, **kwargs) -> None:
    handles: list[Artist] = [Patch(**style) for style in BOX_STYLES.values()]
    handles += [Line2D([], [], **PLAN_STYLE)]
    if marked:
        handles.append(Patch(**VIOLATION_STYLE))
    fig.legend(handles=handles, ncol=len(handles), frameon=False, **kwargs)


def _lanes(outcome: AttackOutcome) -> list[np.ndarray]:
    return [lane.centerline.points for lane in outcome.scenario.lanes]


def bev_figure(outcome: AttackOutcome, seconds_before: float = 3.0, panels: int = 4) -> Figure:
    """The last seconds before the collision, one panel per instant; where the attacked rule breaks before the
    drive ends (any rule but a collision at its closest approach: `violation_mark`), the seconds up to its
    first violation instead, the ego's box there outlined and the suptitle saying what broke. Each panel is
    centred on the ego, where it heads and the agents involved; all share one scale (square, equal aspect)
    so motion compares."""
    scenario, scene = outcome.scenario, _Scene(outcome)
    mark = scene.mark
    last = scene.rollout.num_frames - 1 if mark is None else mark.frame
    first = max(0, last - int(round(seconds_before / scenario.dt)))
    frames = np.unique(np.linspace(first, last, panels).round().astype(int))
    boxes = [scene.involved(k) for k in frames]
    lows, highs = np.array([b.min(axis=0) for b in boxes]), np.array([b.max(axis=0) for b in boxes])
    half = max(MIN_HALF_WIDTH, ((highs - lows).max() / 2.0) + MARGIN)
    centres = (lows + highs) / 2.0
    fig, axes = plt.subplots(1, len(frames), figsize=(3.6 * len(frames), 4.0), squeeze=False)
    for ax, k, centre in zip(axes[0], frames, centres):
        ax.add_collection(LineCollection(_lanes(outcome), **LANE_STYLE))
        ax.plot(scene.rollout.ego[: k + 1, 0], scene.rollout.ego[: k + 1, 1], color="tab:red", linewidth=0.8)
        for name, corners in scene.boxes(k).items():
            # matplotlib's stub wants a sequence of polygons; it documents (and has a fast path for) an (N, M, 2) array
            ax.add_collection(PolyCollection(corners, **_unlabelled(BOX_STYLES[name])))  # type: ignore[arg-type]
        plan = scene.plan(k)
        ax.plot(plan[:, 0], plan[:, 1], **_unlabelled(PLAN_STYLE))
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_aspect("equal")
        if mark is not None and k == mark.frame:
            ego = scene.boxes(k)["ego"]
            ax.add_collection(PolyCollection(ego, **_unlabelled(VIOLATION_STYLE)))  # type: ignore[arg-type]  # as above
            what = f" ({mark.rule} violated)"
        else:
            what = " (collision)" if k == last and scene.ended_in_contact else ""
        ax.set_title(f"t = {scenario.times[k]:.1f} s{what}", fontsize=10)
        ax.tick_params(labelsize=8)
        ax.grid(alpha=0.2)
    span = (f"the last {seconds_before:g} s of the attack" if mark is None
            else f"the {seconds_before:g} s up to the violation: {mark.label}")
    fig.suptitle(f"{scenario.name}: {span} (map frame, m)", fontsize=11)
    _legend(fig, mark is not None, loc="lower center", fontsize=9)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    return fig


def _unlabelled(style: dict) -> dict:
    return {k: v for k, v in style.items() if k != "label"}


def birds_eye_view(path: Path, outcome: AttackOutcome, seconds_before: float = 3.0) -> None:
    _save(bev_figure(outcome, seconds_before), path, dpi=110)


def _to_ego(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Map points (..., 2) into the ego frame of pose (x, y, yaw): x ahead, y to the left."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    d = points - pose[:2]
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)


def animation_frames(outcome: AttackOutcome) -> np.ndarray:
    """Frames of the recorded rollout the animation shows: every GIF_PERIOD, at most GIF_MAX_FRAMES,
    always ending on the last (the collision)."""
    last = _recorded(outcome).num_frames - 1
    step = max(1, int(round(GIF_PERIOD / outcome.scenario.dt)), int(np.ceil((last + 1) / GIF_MAX_FRAMES)))
    return np.arange(last, -1, -step)[::-1]


def attack_animation(path: Path, outcome: AttackOutcome, dpi: int = 72) -> None:
    """The whole attack rollout as a GIF in the ego's frame (it drives to the right), so the axes never
    move and can be blitted: the static figure is drawn once, each frame redraws only the moving artists.
    (matplotlib's PillowWriter redraws the whole figure per frame, several times the cost; the frames go
    to Pillow the way it hands them over.)"""
    scene, scenario = _Scene(outcome), outcome.scenario
    fig, ax = plt.subplots(figsize=(5.6, 3.4), dpi=dpi)
    lanes = LineCollection([], animated=True, **LANE_STYLE)
    ax.add_collection(lanes)
    layers: dict[str, PolyCollection] = {}
    for name, style in BOX_STYLES.items():
        layers[name] = PolyCollection([], animated=True, **_unlabelled(style))
        ax.add_collection(layers[name])
    (plan,) = ax.plot([], [], animated=True, **_unlabelled(PLAN_STYLE))
    label = ax.text(0.01, 0.98, "", transform=ax.transAxes, va="top", fontsize=8, family="monospace", animated=True,
                    bbox=dict(facecolor="white", alpha=0.8, edgecolor="none", pad=1.5))
    ax.set_xlim(*GIF_WINDOW[0])
    ax.set_ylim(*GIF_WINDOW[1])
    ax.set_aspect("equal")
    ax.set_xlabel("m ahead of the ego", fontsize=8)
    ax.set_ylabel("m to its left", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.2)
    title = ax.set_title(f"{scenario.name}: attack on the {outcome.params.planner} planner", fontsize=9)
    mark = scene.mark
    if mark is not None:  # from the violation on, the title says so: drawn per frame
        title.set_animated(True)
    _legend(fig, loc="lower center", fontsize=7, handlelength=1.2, columnspacing=1.0)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    canvas = fig.canvas
    assert isinstance(canvas, FigureCanvasAgg)  # matplotlib.use("Agg") above: blitting and the RGBA buffer are Agg's
    canvas.draw()
    background = canvas.copy_from_bbox(fig.bbox)
    _, slot = scene.rollout.closest_approach()
    agent = int(scenario.agents.ids[:, slot][scenario.agents.valid[:, slot]][0])
    last = scene.rollout.num_frames - 1
    moving: list[Artist] = [lanes, *layers.values(), plan, label, *([title] if mark is not None else [])]
    planner_title = title.get_text()
    images = []
    for k in animation_frames(outcome):
        pose = scene.rollout.ego[k, :3]
        lanes.set_segments([_to_ego(points, pose) for points in _lanes(outcome)])
        for name, corners in scene.boxes(k).items():
            layers[name].set_verts(_to_ego(corners, pose))  # type: ignore[arg-type]  # an (N, 4, 2) array, as above
        plan.set_data(*_to_ego(scene.plan(k), pose).T)
        text = f"t = {scenario.times[k]:4.1f} s   nearest agent {scene.rollout.rule[k]:5.2f} m"
        if mark is not None:
            text += f"\n{mark.rule} r = {mark.per_frame[k]:5.2f} {mark.unit}"
            title.set_text(mark.label if k >= mark.frame else planner_title)
            title.set_color("tab:purple" if k >= mark.frame else "black")
        if k == last and scene.ended_in_contact:
            text += f"\ncollision with agent {agent}"
        label.set_text(text)
        canvas.restore_region(background)
        for artist in moving:
            ax.draw_artist(artist)
        images.append(Image.frombuffer("RGBA", canvas.get_width_height(), canvas.buffer_rgba(), "raw", "RGBA", 0, 1)
                      .convert("RGB"))
    plt.close(fig)
    _write_gif(path, images)


def _write_gif(path: Path, images: list[Image.Image]) -> None:
    """One palette for all frames, from the first, middle and last: Pillow's per-frame quantisation would
    cost most of the animation's time and double its size, and the figure has few colours."""
    width, height = images[0].size
    sample = Image.new("RGB", (width, 3 * height))
    for i, image in enumerate((images[0], images[len(images) // 2], images[-1])):
        sample.paste(image, (0, i * height))
    palette = sample.quantize(colors=48, method=Image.Quantize.MAXCOVERAGE, dither=Image.Dither.NONE)
    frames = [image.quantize(palette=palette, dither=Image.Dither.NONE) for image in images]
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=round(1000 * GIF_PERIOD), loop=0)


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
    right.set_ylabel(METRIC_NAMES.get(objective, objective))
    for ax in (left, right):
        ax.grid(alpha=0.3)
    fig.suptitle("Robustness of the attack to random perturbations")
    fig.tight_layout()
    _save(fig, path, dpi=120)


BAR_SCENARIOS = 6  # up to this many scenarios a requirements plot draws bars; beyond, one point per scenario
NAMED_PER_BIN = 4  # broken brackets of one bin named on the plot, at most


def requirements(path: Path, brackets) -> None:
    """One error kind's perception requirement against distance from the ego (`advperc requirements`). For a few
    scenarios, a bar each per distance bin, from 0 up to the tolerated magnitude (solid) and on to the one that
    broke the rule (hatched), pale and marked "not broken" where nothing broke it up to the largest magnitude
    searched. For many (a run across recordings), one mark each per bin, spread across it: the bracket as a
    line from the tolerated magnitude to the broken one, a triangle where nothing broke it, a cross at 0 where
    the ground truth already breaks the rule; the broken ones named where a bin has few."""
    fig, ax = plt.subplots(figsize=(6.5, 3.6))
    scenarios = list(dict.fromkeys(b.scenario for b in brackets))
    bins = list(dict.fromkeys((b.near, b.far) for b in brackets))
    if len(scenarios) <= BAR_SCENARIOS:
        _requirement_bars(ax, brackets, scenarios, bins)
    else:
        _requirement_marks(ax, brackets, scenarios, bins)
    kind, unit = brackets[0].kind, brackets[0].unit
    ax.set_xticks(range(len(bins)), [f"{near:g}-{far:g} m" for near, far in bins])
    ax.set_xlabel("distance from the ego")
    ax.set_ylabel(f"{kind} ({unit})")
    ax.set_ylim(0, max(b.breaks_at or b.tolerated for b in brackets) * 1.15 or 1.0)
    ax.grid(alpha=0.3, axis="y")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)
    fig.tight_layout()
    _save(fig, path, dpi=120)


def _requirement_bars(ax, brackets, scenarios: list[str], bins: list[tuple[float, float]]) -> None:
    width = 0.8 / max(len(scenarios), 1)
    for s, scenario in enumerate(scenarios):
        color = f"C{s % 10}"
        for b in (b for b in brackets if b.scenario == scenario):
            x = bins.index((b.near, b.far)) - 0.4 + width * (s + 0.5)
            first = (b.near, b.far) == bins[0]
            broken = b.breaks_at is not None
            ax.bar(x, b.tolerated, width * 0.9, color=color, alpha=1.0 if broken else 0.35,
                   label=scenario if first else None)
            if b.ground_truth_breaks is not None:
                ax.text(x, 0.0, "collides unattacked", ha="center", va="bottom", fontsize=7, rotation=90)
            elif broken:
                ax.bar(x, b.breaks_at - b.tolerated, width * 0.9, bottom=b.tolerated, color="none", edgecolor=color,
                       hatch="//")
            else:  # nothing broke it up to the largest magnitude searched: a floor, not a bracket
                ax.text(x, b.tolerated, "not broken", ha="center", va="bottom", fontsize=7)
    ax.set_title(f"{brackets[0].kind}: tolerated (solid) and broken at (hatched)")


def _requirement_marks(ax, brackets, scenarios: list[str], bins: list[tuple[float, float]]) -> None:
    spread = np.linspace(-0.35, 0.35, len(scenarios))
    said: set[str] = set()
    broken = Counter((b.near, b.far) for b in brackets if b.breaks_at is not None and b.ground_truth_breaks is None)
    for b in brackets:
        x = bins.index((b.near, b.far)) + spread[scenarios.index(b.scenario)]
        if b.ground_truth_breaks is not None:
            style, label = {"marker": "x", "color": "C3"}, "ground truth breaks the rule"
        elif b.breaks_at is None:
            style, label = {"marker": "^", "color": "0.6"}, "not broken up to this"
        else:
            style, label = {"marker": "o", "color": "C0"}, "tolerated, line to broken at"
            ax.plot([x, x], [b.tolerated, b.breaks_at], color="C0", lw=2)
            if broken[(b.near, b.far)] <= NAMED_PER_BIN:  # more would overlap: the table names them
                ax.annotate(b.scenario, (x, b.breaks_at), fontsize=6, rotation=90, ha="center", va="bottom",
                            xytext=(0, 2), textcoords="offset points")
        ax.plot([x], [b.tolerated], linestyle="none", markersize=5, label=None if label in said else label, **style)
        said.add(label)
    ax.set_title(f"{brackets[0].kind}: tolerated per scenario ({len(scenarios)} scenarios)")
