"""Every kind of bad input we know of, across every command: one line naming the file and the
field, exit code 2, and nothing written. The table of them in docs/commands.md is produced from
`CASES` (`ADVPERC_WRITE_DOCS=1 python -m pytest test/cli/test_bad_input.py` rewrites it), so it cannot drift.
"""

import dataclasses
import json
import os
import re
import shutil
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import yaml

from advperc_ros.application import output_lock
from advperc_ros.backends.resumed import ROLLOUTS, Checkpoint, checkpoint_folder
from advperc_ros.cli import main
from advperc_ros.configs import core_configs
from advperc_ros.core.perception_errors import PerceptionErrors
from advperc_ros.core.rollout import RolloutResult
from advperc_ros.params import load_params
from advperc_ros.results.destination import exclusive
from advperc_ros.ros.bag import read_scenario
from conftest import REPO
from test_check_bag import boxes, write_bag

GOOD_BAG = REPO / "bags" / "idm_lane_following"
DOCS_PAGE = Path("docs") / "commands.md"  # the Commands page, section "Bad input"
TABLE_START = "<!-- bad-input table: test/cli/test_bad_input.py -->"
TABLE_END = "<!-- end of bad-input table -->"


@dataclass(frozen=True)
class Case:
    command: str  # as the docs table shows it
    bad: str  # what is wrong, as the docs table shows it
    argv: Callable[[Path], list[str]]  # builds the inputs in a folder, returns the arguments
    says: str  # what the error line must contain (the field, or what is wrong with it)
    names_file: str | None = "?"  # a file name the line must contain ("?": the first file argument)
    setup: Callable[[pytest.MonkeyPatch], None] | None = None  # the machine's part of the case (a full disk)


def _params(folder: Path, text: str | None = None, **changes) -> str:
    """A valid params file with a short search, changed by dotted `changes` (None deletes), or `text`."""
    path = folder / "p.yaml"
    if text is not None:
        path.write_bytes(text.encode("latin-1") if isinstance(text, str) else text)
        return str(path)
    document = yaml.safe_load((REPO / "config" / "idm_lane_following.yaml").read_text())
    params = document["orchestrator"]["ros__parameters"]
    params.update(bag=str(GOOD_BAG), search={"heuristic": {"iterations": 1}, "random": {"steps": 2}})
    for dotted, value in changes.items():
        node = params
        *parents, leaf = dotted.split(".")
        for key in parents:
            node = node.setdefault(key, {})
        if value is None:
            node.pop(leaf, None)
        else:
            node[leaf] = value
    path.write_text(yaml.safe_dump(document))
    return str(path)


def attack(**changes) -> Callable[[Path], list[str]]:
    return lambda folder: ["attack", _params(folder, **changes), "--output", str(folder / "out"), "--quiet"]


def attack_text(text) -> Callable[[Path], list[str]]:
    return lambda folder: ["attack", _params(folder, text=text), "--output", str(folder / "out"), "--quiet"]


def attack_flags(*flags: str) -> Callable[[Path], list[str]]:
    return lambda folder: ["attack", _params(folder), "--output", str(folder / "out"), "--quiet", *flags]


def attack_bag(**bag) -> Callable[[Path], list[str]]:
    def build(folder: Path) -> list[str]:
        path = write_bag(folder / "bag", **bag)
        return ["attack", _params(folder, bag=str(path)), "--output", str(folder / "out"), "--quiet"]
    return build


def check_bag(**bag) -> Callable[[Path], list[str]]:
    return lambda folder: ["check-bag", str(write_bag(folder / "bag", **bag))]


def _results(folder: Path, report: object = None, errors: bytes | None = None) -> Path:
    """A results folder as robustness reads it: report.json (a real one unless given) and the errors."""
    results = folder / "results"
    results.mkdir()
    if report is None:
        params = yaml.safe_load(Path(_params(folder)).read_text())["orchestrator"]["ros__parameters"]
        flat = {"bag": params["bag"], "planner": "idm", "objective": "nds_t", "seed": 0}
        report = {"bag": str(GOOD_BAG), "params": {**flat, "planner_params": {"target_speed": 14.0}}}
    (results / "report.json").write_text(report if isinstance(report, str) else json.dumps(report))
    shape = (251, 5)
    if errors is None:
        buffer = folder / "e.npz"
        np.savez(buffer, dx=np.zeros(shape), dy=np.zeros(shape), dyaw=np.zeros(shape), fn=np.zeros(shape, bool))
        errors = buffer.read_bytes()
        buffer.unlink()
    (results / "attack_errors.npz").write_bytes(errors)
    return results


def robustness(*flags: str, **results) -> Callable[[Path], list[str]]:
    return lambda folder: ["robustness", str(_results(folder, **results)), *flags]


def typical(*flags: str) -> Callable[[Path], list[str]]:
    return lambda folder: ["check-typical", _params(folder), *flags]


def model(text: str) -> Callable[[Path], list[str]]:
    def build(folder: Path) -> list[str]:
        (folder / "pem.json").write_text(text)
        return ["check-typical", _params(folder), "--samples", "1", "--model", str(folder / "pem.json")]
    return build


def resume(damage: Callable[[Path], object]) -> Callable[[Path], list[str]]:
    """`attack --resume` of an output whose checkpoint (three rollouts, as an attack writes them) `damage`
    changed; `damage` gets the checkpoint folder."""
    def build(folder: Path) -> list[str]:
        params = _params(folder)
        _checkpoint(folder / "out", params)
        damage(checkpoint_folder(folder / "out"))
        return ["attack", params, "--resume", str(folder / "out"), "--quiet"]
    return build


def _checkpoint(output: Path, params: str, seed: int = 0) -> None:
    """A checkpoint of three made-up rollouts of the good bag, written by the attack's own writer."""
    scenario = read_scenario(GOOD_BAG)
    frames, agents = scenario.agents.shape
    checkpoint = Checkpoint(output, core_configs(dataclasses.replace(load_params(params), seed=seed)).canonical, scenario,
                            resume=False)
    for k in range(3):
        errors = PerceptionErrors.none(frames, agents)
        errors.dx[k] = 1.0
        checkpoint.append(errors, RolloutResult(ego=np.full((frames, 4), float(k)), distances=np.full((frames, agents), 9.5)))
    checkpoint.close(finished=False)


def _rollouts(change: Callable[[list], object]) -> Callable[[Path], None]:
    """A damage of the rollouts file: `change` edits its list of lines (as bytes) in place."""
    def damage(checkpoint: Path) -> None:
        lines = (checkpoint / ROLLOUTS).read_bytes().splitlines()
        change(lines)
        (checkpoint / ROLLOUTS).write_bytes(b"".join(line + b"\n" for line in lines))
    return damage


def _second_line(change: Callable[[dict], object]) -> Callable[[Path], None]:
    """A damage of the second line's JSON value: `change` edits it in place."""
    def edit(lines: list) -> None:
        line = json.loads(lines[1])
        change(line)
        lines[1] = json.dumps(line).encode()
    return _rollouts(edit)


def _splice(checkpoint: Path) -> None:
    """The second line replaced by the second line of another attack's (seed 1) checkpoint."""
    other = checkpoint.parent / "other"
    _checkpoint(other, str(checkpoint.parent / "p.yaml"), seed=1)
    theirs = (checkpoint_folder(other) / ROLLOUTS).read_bytes().splitlines()[1]
    shutil.rmtree(checkpoint_folder(other))
    _rollouts(lambda lines: lines.__setitem__(1, theirs))(checkpoint)


HELD = ExitStack()  # the output locks of the attacks `running` stands for, held as they would hold them


def running(*flags: str) -> Callable[[Path], list[str]]:
    """`attack` onto an output another attack is running on (its lock held)."""
    def build(folder: Path) -> list[str]:
        HELD.enter_context(exclusive(output_lock(folder / "out"), "held"))
        return ["attack", _params(folder), *flags, str(folder / "out"), "--quiet"]
    return build


def _cases() -> list[Case]:
    cases = [
        Case("advperc attack P.yaml", "params file missing", lambda f: ["attack", str(f / "none.yaml")], "no such params file"),
        Case("advperc attack P.yaml", "params path is a folder", lambda f: ["attack", str(f)], "cannot read params file"),
        Case("advperc attack P.yaml", "binary params file", attack_text(b"\xff\xfe\x00\x01"), "cannot read params file"),
        Case("advperc attack P.yaml", "Latin-1 (not UTF-8) params file", attack_text("bag: caf\xe9\n"), "cannot read params file"),
        Case("advperc attack P.yaml", "empty params file", attack_text(""), "'orchestrator:'"),
        Case("advperc attack P.yaml", "YAML syntax error", attack_text("orchestrator: [\n"), "cannot read params file"),
        Case("advperc attack P.yaml", "top level a list", attack_text("- 1\n"), "'orchestrator:'"),
        Case("advperc attack P.yaml", "another node's name", attack_text("planner:\n  ros__parameters: {}\n"), "'orchestrator:'"),
        Case("advperc attack P.yaml", "two nodes", attack_text("orchestrator:\n  ros__parameters: {bag: x}\nx: 1\n"), "unknown node 'x'"),
        Case("advperc attack P.yaml", "no ros__parameters", attack_text("orchestrator: {bag: x}\n"), "ros__parameters"),
        Case("advperc attack P.yaml", "ros__parameters a list", attack_text("orchestrator:\n  ros__parameters: [1]\n"), "ros__parameters"),
        Case("advperc attack P.yaml", "a key given twice (YAML keeps the last silently)", attack_text("orchestrator:\n  ros__parameters:\n    seed: 1\n    seed: 2\n"), "given twice"),
        Case("advperc attack P.yaml", "a recursive YAML anchor", attack_text("orchestrator:\n  ros__parameters: &a\n    bag: *a\n"), "refers to itself"),
        Case("advperc attack P.yaml", "params file a FIFO (would block)", lambda f: os.mkfifo(f / "p.yaml") or ["attack", str(f / "p.yaml"), "--output", str(f / "out")], "not a regular file"),
        Case("advperc attack P.yaml", "params file a device (`/dev/zero`, endless)", lambda f: ["attack", "/dev/zero", "--output", str(f / "out")], "not a regular file", "/dev/zero"),
        Case("advperc attack P.yaml", "unknown parameter", attack(**{"search.random.stepz": 3}), "unknown parameter 'search.random.stepz'"),
        Case("advperc attack P.yaml", "`bag` missing", attack(bag=None), "'bag' is required"),
        Case("advperc attack P.yaml", "`rule.name` not a rule of the rulebook", attack(**{"rule.name": "speeding"}), "'rule.name' must be one of"),
        Case("advperc attack P.yaml", "`rule.at_fault_only` with another rule than the collision rule", attack(**{"rule.name": "progress", "rule.at_fault_only": True}), "'rule.at_fault_only' is true, but it is of the collision rule"),
        Case("advperc attack P.yaml", "`traffic.braking_max` 0 (a traffic parameter out of its bounds)", attack(**{"traffic.braking_max": 0.0}), "'traffic.braking_max' must be positive"),
        Case("advperc attack P.yaml", "`traffic.reactive` not a boolean", attack(**{"traffic.reactive": "yes"}), "'traffic.reactive' must be of type bool"),
        Case("advperc attack P.yaml", "`bag` names nothing", attack(bag="bags/no_such_bag"), "'bag' names 'bags/no_such_bag'"),
        Case("advperc attack P.yaml", "`bag` a number", attack(bag=3), "'bag' must be of type str"),
        Case("advperc attack P.yaml", "`planner` unknown", attack(planner="fast"), "unknown planner 'fast'", None),
        Case("advperc attack P.yaml", "`graph.interface` no profile", attack(**{"graph.interface": "ros1"}),
             "'graph.interface' must be one of advperc, autoware"),
        Case("advperc attack P.yaml", "`planner` module missing", attack(planner="no_such_mod:P"), "planner 'no_such_mod:P' cannot be imported", None),
        Case("advperc attack P.yaml", "`planner` class missing", attack(planner="json:NoSuchPlanner"), "planner 'json:NoSuchPlanner' cannot be imported", None),
        Case("advperc attack P.yaml", "`planner` a class of something else", attack(planner="json:JSONDecoder"), "rejected its parameters", None),
        Case("advperc attack P.yaml", "`planner` a number", attack(planner=1), "'planner' must be of type str"),
        Case("advperc attack P.yaml", "`planner_params` a list", attack(planner_params=[1]), "'planner_params' must be a mapping"),
        Case("advperc attack P.yaml", "`planner_params` nested", attack(planner_params={"a": {"b": 1}}), "'planner_params.a' must be a finite scalar"),
        Case("advperc attack P.yaml", "`planner_params` NaN", attack(planner_params={"target_speed": float("nan")}), "'planner_params.target_speed'"),
        Case("advperc attack P.yaml", "IDM parameter unknown", attack(planner_params={"speed": 3.0}), "speed", None),
        Case("advperc attack P.yaml", "IDM target speed negative", attack(planner_params={"target_speed": -14.0}), "target_speed", None),
        Case("advperc attack P.yaml", "IDM target speed a word", attack(planner_params={"target_speed": "fast"}), "target_speed", None),
        Case("advperc attack P.yaml", "ObP horizon zero", attack(planner="obp", planner_params={"horizon": 0.0}), "horizon", None),
        Case("advperc attack P.yaml", "`objective` unknown", attack(objective="map"), "'objective' must be one of nds, nds_t, pem_ll"),
        Case("advperc attack P.yaml", "`seed` negative", attack(seed=-1), "'seed' must be at least 0"),
        Case("advperc attack P.yaml", "`seed` beyond int64", attack(seed=2**70), "'seed' must be at most"),
        Case("advperc attack P.yaml", "`seed` a float", attack(seed=1.5), "'seed' must be of type int"),
        Case("advperc attack P.yaml", "`seed` a word", attack(seed="zero"), "'seed' must be of type int"),
        Case("advperc attack P.yaml", "`stop_at_collision` a word", attack(stop_at_collision="yes"), "'stop_at_collision' must be of type bool"),
        Case("advperc attack P.yaml", "`stop_at_collision` 1", attack(stop_at_collision=1), "'stop_at_collision' must be of type bool"),
        Case("advperc attack P.yaml", "`rollout_backend` unknown", attack(rollout_backend="gpu"), "'rollout_backend' must be one of"),
        Case("advperc attack P.yaml", "`fork_memory` negative", attack(fork_memory=-1), "'fork_memory' must be at least 0"),
        Case("advperc attack P.yaml --fork-memory", "`--fork-memory` negative",
             lambda f: ["attack", _params(f), "--fork-memory", "-1", "--output", str(f / "out")], "'fork_memory' must be at least 0"),
    ]
    floats = {"ego.length": 4.6, "ego.width": 1.9, "tracker.gate": 2.0, "tracker.max_age": 1.0,
              "search.random.max_offset": 5.0, "graph.timeout": 10.0}
    for name in floats:
        cases += [
            Case("advperc attack P.yaml", f"`{name}` zero", attack(**{name: 0.0}), f"'{name}' must be positive"),
            Case("advperc attack P.yaml", f"`{name}` an integer", attack(**{name: 3}), f"'{name}' must be a float (write 3.0)"),
            Case("advperc attack P.yaml", f"`{name}` .nan", attack(**{name: float("nan")}), f"'{name}' must be a finite number"),
        ]
    cases += [
        Case("advperc attack P.yaml", "`ego.length` negative", attack(**{"ego.length": -4.6}), "'ego.length' must be positive"),
        Case("advperc attack P.yaml", "`search.random.max_offset` .inf", attack(**{"search.random.max_offset": float("inf")}), "'search.random.max_offset' must be a finite number"),
        Case("advperc attack P.yaml", "`search.random.yaw_std` negative", attack(**{"search.random.yaw_std": -0.1}), "'search.random.yaw_std' must be at least 0"),
        Case("advperc attack P.yaml", "`errors.kinds` naming no kind", attack(**{"errors.kinds": "drop,ghosts"}), "'errors.kinds': unknown error kind 'ghosts'"),
        Case("advperc attack P.yaml", "`errors.kinds` beyond the paper's with `search.method: paper`", attack(**{"errors.kinds": "all", "search.method": "paper"}), "'errors.kinds' must be paper with search.method paper"),
        Case("advperc attack P.yaml", "`requirement.kind` flip (no magnitude to bound)", attack(**{"requirement.kind": "flip"}), "'requirement.kind' must be one of"),
        Case("advperc attack P.yaml", "`requirement.kind` velocity with `errors.kinds` paper", attack(**{"requirement.kind": "velocity", "requirement.magnitude": 1.0}), "'requirement.kind' is velocity, which errors.kinds"),
        Case("advperc attack P.yaml", "`requirement.far` below `requirement.near`", attack(**{"requirement.kind": "drop", "requirement.near": 20.0, "requirement.far": 10.0}), "'requirement.far' must be above requirement.near"),
        Case("advperc attack P.yaml", "`requirement.magnitude` -1.0", attack(**{"requirement.kind": "drop", "requirement.magnitude": -1.0}), "'requirement.magnitude' must be at least 0"),
        Case("advperc attack P.yaml", "`errors.min_scale` 0", attack(**{"errors.min_scale": 0.0}), "'errors.min_scale' must be positive"),
        Case("advperc attack P.yaml --errors", "`--errors` naming no kind", lambda f: ["attack", _params(f), "--errors", "lateness", "--output", str(f / "out")], "unknown error kind 'lateness'"),
        Case("advperc attack P.yaml", "`search.random.yaw_std` .inf", attack(**{"search.random.yaw_std": float("inf")}), "'search.random.yaw_std' must be a finite number"),
        Case("advperc attack P.yaml", "`search.random.proposals` 0", attack(**{"search.random.proposals": 0}), "'search.random.proposals' must be at least 1"),
        Case("advperc attack P.yaml", "`search.random.steps` negative", attack(**{"search.random.steps": -1}), "'search.random.steps' must be at least 0"),
        Case("advperc attack P.yaml", "`search.random.steps` a float", attack(**{"search.random.steps": 4.0}), "'search.random.steps' must be of type int"),
        Case("advperc attack P.yaml", "`search.heuristic.iterations` negative", attack(**{"search.heuristic.iterations": -1}), "'search.heuristic.iterations' must be at least 0"),
        Case("advperc attack P.yaml", "`search.heuristic.iterations` huge", attack(**{"search.heuristic.iterations": 1000}), "'search.heuristic.iterations' must be at most 64"),
        Case("advperc attack P.yaml", "`search.refine.iterations` negative", attack(**{"search.refine.iterations": -1}), "'search.refine.iterations' must be at least 0"),
        Case("advperc attack P.yaml", "`search.random` a number", attack(**{"search.random": 3}), "unknown parameter 'search.random'"),
        Case("advperc attack P.yaml", "`search.guided.candidates` a million (memory)", attack(**{"search.guided.candidates": 1_000_000}), "'search.guided.candidates' must be at most 10000"),
        Case("advperc attack P.yaml", "`search.random.proposals` a million (memory)", attack(**{"search.random.proposals": 1_000_000}), "'search.random.proposals' must be at most 10000"),
        Case("advperc attack P.yaml", "`graph.timeout` 1e-300 (every plan timed out, after the ground truth's rollout)", attack(**{"graph.timeout": 1e-300}), "'graph.timeout' must be at least 0.001"),
        Case("advperc attack P.yaml", "`ego.length` 1e300 (caught after the ground truth's rollout)", attack(**{"ego.length": 1e300}), "'ego.length' must be at most 60"),
        Case("advperc attack P.yaml", "`graph.timeout` 1e10 (beyond any alarm)", attack(**{"graph.timeout": 1e10}), "'graph.timeout' must be at most 3600"),
        Case("advperc attack P.yaml", "IDM horizon 1e9 s (memory)", attack(planner_params={"horizon": 1e9}), "'horizon' must be at most 60", None),
        Case("advperc attack P.yaml", "ObP horizon 1e9 s", attack(planner="obp", planner_params={"horizon": 1e9}), "'horizon' must be at most 30", None),
        Case("advperc attack P.yaml", "`search.budget` 3, below one drop per agent (it crashed after the work)", attack(**{"search.budget": 3}), "'search.budget' is 3, below the 6 rollouts"),
        Case("advperc attack P.yaml", "`dds.domain_id` 300", attack(**{"dds.domain_id": 300}), "'dds.domain_id' must be at most 232"),
        Case("advperc attack P.yaml", "`dds.domain_id` negative", attack(**{"dds.domain_id": -1}), "'dds.domain_id' must be at least 0"),
        Case("advperc attack P.yaml", "`dds.localhost_only` a word", attack(**{"dds.localhost_only": "true"}), "'dds.localhost_only' must be of type bool"),
        Case("advperc attack P.yaml", "`graph.spawn_nodes` 0", attack(**{"graph.spawn_nodes": 0}), "'graph.spawn_nodes' must be of type bool"),
        Case("advperc attack P.yaml --seed", "`--seed -5`", attack_flags("--seed", "-5"), "'seed' must be at least 0"),
        Case("advperc attack P.yaml --seed", "`--seed abc`", attack_flags("--seed", "abc"), "--seed", None),
        Case("advperc attack P.yaml --objective", "`--objective map`", attack_flags("--objective", "map"), "--objective", None),
        Case("advperc attack P.yaml --backend", "`--backend gpu`", attack_flags("--backend", "gpu"), "--backend", None),
        Case("advperc attack P.yaml --method", "`--method random`", attack_flags("--method", "random"), "--method", None),
        Case("advperc attack P.yaml --output", "output folder exists", lambda f: (f / "out").mkdir() or ["attack", _params(f), "--output", str(f / "out")], "exists already", "out"),
        Case("advperc attack P.yaml --output", "output under a file", lambda f: (f / "file").write_text("x") and ["attack", _params(f), "--output", str(f / "file" / "out")], "is not a folder", "file"),
        Case("advperc attack P.yaml --output", "output where nothing can be made (`/proc`, a read-only mount: root passes access() there)", lambda f: ["attack", _params(f), "--output", "/proc/advperc-out"], "cannot create the output folder", "/proc/advperc-out"),
        Case("advperc attack P.yaml --output", "`--output ''`", attack_flags("--output", ""), "an empty path names nothing", None),
        Case("advperc attack P.yaml --output", "output a symbolic link to nothing", lambda f: _link(f / "out", "nowhere") or ["attack", _params(f), "--output", str(f / "out")], "is a symbolic link", "out"),
        Case("advperc attack P.yaml --output", "output a symbolic link loop", lambda f: _link(f / "out", "out") or ["attack", _params(f), "--output", str(f / "out")], "is a symbolic link", "out"),
        Case("advperc attack P.yaml --output", "output under a symbolic link loop", lambda f: _link(f / "loop", "loop") or ["attack", _params(f), "--output", str(f / "loop" / "out")], "symbolic link loop", "loop"),
        Case("advperc attack P.yaml --output", "output under a symbolic link to nothing", lambda f: _link(f / "gone", "nowhere") or ["attack", _params(f), "--output", str(f / "gone" / "out")], "symbolic link to nothing", "gone"),
        Case("advperc attack P.yaml --output", "output named by `..` (a folder that exists once its parent is made)", lambda f: ["attack", _params(f), "--output", str(f / "new" / "..")], "not by '..'", None),
        Case("advperc attack P.yaml --output", "output climbing with `..` out of a folder still to be made (`new/../new`)", lambda f: ["attack", _params(f), "--output", str(f / "new" / ".." / "new")], "climbs with '..'", None),
        Case("advperc attack P.yaml --output", "output name over 255 bytes", lambda f: ["attack", _params(f), "--output", str(f / ("o" * 300))], "longer than the file system allows", None),
        Case("advperc attack P.yaml --output", "output on a disk without room for the run's estimate", attack_flags(), "MiB free", "out",
             setup=_disk_with_one_mib_free),
        Case("advperc attack P.yaml --resume", "`--resume` and another `--output`", attack_flags("--resume", "elsewhere"), "give the folder once", None),
        Case("advperc attack P.yaml --resume", "checkpoint line `{}`", resume(_rollouts(lambda lines: lines.__setitem__(1, b"{}"))), "line 2: not a checkpointed rollout", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint line `[1, 2]`", resume(_rollouts(lambda lines: lines.__setitem__(1, b"[1, 2]"))), "line 2: not a checkpointed rollout", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint line `null`", resume(_rollouts(lambda lines: lines.__setitem__(1, b"null"))), "line 2: not a checkpointed rollout", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint line not UTF-8", resume(_rollouts(lambda lines: lines.__setitem__(1, b"\xff" + lines[1]))), "line 2 is not JSON", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint line cut short, not the last (damage, not a kill)", resume(_rollouts(lambda lines: lines.__setitem__(1, lines[1][:100]))), "line 2 is not JSON", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint line without `chain`", resume(_second_line(lambda line: line.pop("chain"))), "line 2: not a checkpointed rollout", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint `errors` not a digest", resume(_second_line(lambda line: line.update(errors="x"))), "'errors' is not a sha256 digest", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint `ego` row of 3 numbers", resume(_second_line(lambda line: line["ego"][7].pop())), "'ego' row 7 is not a list of 4 values", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint `ego` value NaN", resume(_second_line(lambda line: line["ego"][7].__setitem__(0, float("nan")))), "'ego' row 7 column 0 is not a finite number", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint `ego` value a string", resume(_second_line(lambda line: line["ego"][7].__setitem__(0, "1.0"))), "'ego' row 7 column 0 is not a finite number", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint `ego` longer than the bag", resume(_second_line(lambda line: line["ego"].append([0.0] * 4))), "'ego' is not a list of 1 to 251 rows", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint `distances` a row short of `ego`", resume(_second_line(lambda line: line["distances"].pop())), "'distances' is not a list of 251 rows", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint `distances` of 4 agents (the bag has 5)", resume(_second_line(lambda line: line["distances"][0].pop())), "'distances' row 0 is not a list of 5 values", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint distance `true`", resume(_second_line(lambda line: line["distances"][0].__setitem__(0, True))), "'distances' row 0 column 0 is not a finite number or null", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint `planner_failures` -1", resume(_second_line(lambda line: line.update(planner_failures=-1))), "'planner_failures' is neither null nor a count", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint `inconclusive` a number", resume(_second_line(lambda line: line.update(inconclusive=3))), "'inconclusive' is neither null nor a string", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint distance edited by hand (it was used silently)", resume(_second_line(lambda line: line["distances"][0].__setitem__(0, 2.5))), "line 2 was changed after it was written", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint lines reordered", resume(_rollouts(lambda lines: lines.reverse())), "line 1 was changed after it was written, moved", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint line of another attack's checkpoint", resume(_splice), "comes from another attack's checkpoint", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint folder a file", resume(lambda c: shutil.rmtree(c) or c.write_text("x")), "not a folder", ".out.checkpoint"),
        Case("advperc attack P.yaml --resume", "checkpoint `rollouts.jsonl` a folder", resume(lambda c: (c / ROLLOUTS).unlink() or (c / ROLLOUTS).mkdir()), "missing or not a regular file", "rollouts.jsonl"),
        Case("advperc attack P.yaml --resume", "checkpoint `params.json` missing", resume(lambda c: (c / "params.json").unlink()), "missing or not a regular file", "params.json"),
        Case("advperc attack P.yaml --resume", "checkpoint `params.json` a folder", resume(lambda c: (c / "params.json").unlink() or (c / "params.json").mkdir()), "missing or not a regular file", "params.json"),
        Case("advperc attack P.yaml --resume", "checkpoint of an attack with other params", resume(lambda c: (c / "params.json").write_text("{}")), "the checkpoint is of an attack with other params", "params.json"),
        Case("advperc attack P.yaml --output", "another attack running on that output", running("--output"), "another attack is running on this output", "out"),
        Case("advperc attack P.yaml --resume", "`--resume` of an attack still running (it ran alongside and crashed)", running("--resume"), "another attack is running on this output", "out"),
        Case("advperc attack P.yaml", "bag folder empty", lambda f: (f / "bag").mkdir() or ["attack", _params(f, bag=str(f / "bag"))], "bag", "bag"),
        Case("advperc attack P.yaml", "bag file not MCAP", lambda f: _broken_bag(f) and ["attack", _params(f, bag=str(f / "bag"))], "not a readable rosbag2 bag", "bag"),
        Case("advperc attack P.yaml", "bag without /ground_truth/objects", attack_bag(frames=[]), "/ground_truth/objects", "bag"),
        Case("advperc attack P.yaml", "bag: /ground_truth/objects of another type", attack_bag(wrong_type="/ground_truth/objects"), "/ground_truth/objects", "bag"),
        Case("advperc attack P.yaml", "bag: an id twice in a frame", attack_bag(frames=[boxes([1, 2]), boxes([1, 1]), boxes([1, 2])]), "twice", "bag"),
        Case("advperc attack P.yaml", "bag: stamps out of order", attack_bag(stamps=[0, 200_000_000, 100_000_000, 300_000_000]), "order", "bag"),
        Case("advperc attack P.yaml", "bag: NaN position", attack_bag(frames=[boxes([1]), boxes([1], x=float("nan")), boxes([1])]), "'x'", "bag"),
        Case("advperc attack P.yaml", "bag: position 1e300 (finite; its square is not)", attack_bag(frames=[boxes([1]), boxes([1], x=1e300), boxes([1])]), "'x'", "bag"),
        Case("advperc attack P.yaml", "bag: zero box width", attack_bag(frames=[boxes([1]), boxes([1], width=0.0), boxes([1])]), "'width'", "bag"),
        Case("advperc attack P.yaml", "bag without /ego/odometry", attack_bag(odometry=None), "/ego/odometry", "bag"),
        Case("advperc attack P.yaml", "bag: two /ego/odometry messages (a drive, not a start)", attack_bag(odometry=[(5.0, -1.75, 0.0, 8.0)] * 2), "holds 2 messages", "bag"),
        Case("advperc attack P.yaml", "bag without /ego/route", attack_bag(route=None), "/ego/route", "bag"),
        Case("advperc attack P.yaml", "bag: /ego/odometry of another type", attack_bag(wrong_type="/ego/odometry"), "/ego/odometry", "bag"),
        Case("advperc attack P.yaml", "bag: /clock of another type (it failed after the whole search)", attack_bag(clock=True, wrong_type="/clock"), "topic '/clock' has type", "bag"),
        Case("advperc check-bag BAG", "bag missing", lambda f: ["check-bag", str(f / "none")], "none", "none"),
        Case("advperc check-bag BAG", "an id twice in a frame", check_bag(frames=[boxes([1, 2]), boxes([2, 2])]), "twice", "bag"),
        Case("advperc check-bag BAG", "stamps out of order", check_bag(stamps=[0, 200_000_000, 100_000_000, 300_000_000]), "order", "bag"),
        Case("advperc check-bag BAG", "negative box length", check_bag(frames=[boxes([1]), boxes([1], length=-4.0)]), "'length'", "bag"),
        Case("advperc check-bag BAG", "/clock of another type", check_bag(clock=True, wrong_type="/clock"), "topic '/clock' has type", "bag"),
        Case("advperc check-bag BAG", "infinite speed", check_bag(frames=[boxes([1]), boxes([1], vx=float("inf"))]), "bag", "bag"),
        Case("advperc check-typical P.yaml", "`--samples 0`", typical("--samples", "0"), "--samples", None),
        Case("advperc check-typical P.yaml", "`--samples -3`", typical("--samples", "-3"), "--samples", None),
        Case("advperc check-typical P.yaml --model", "model file missing", typical("--samples", "1", "--model", "none.json"), "none.json", "none.json"),
        Case("advperc check-typical P.yaml --model", "model file a FIFO (it blocked forever)", lambda f: os.mkfifo(f / "pem.json") or ["check-typical", _params(f), "--samples", "1", "--model", str(f / "pem.json")], "not a regular file", "pem.json"),
        Case("advperc check-typical P.yaml --model", "model not JSON", model("{not json"), "pem.json", "pem.json"),
        Case("advperc check-typical P.yaml --model", "model JSON a list", model("[1, 2]"), "pem.json", "pem.json"),
        Case("advperc check-typical P.yaml --model", "model missing a field", model('{"source": "x"}'), "pem.json", "pem.json"),
        Case("advperc requirements P.yaml", "`--kinds` flip (no magnitude to bound)", lambda f: ["requirements", _params(f), "--output", str(f / "out"), "--kinds", "flip"], "--kinds has 'flip'", None),
        Case("advperc requirements P.yaml", "`--kinds` naming a kind twice", lambda f: ["requirements", _params(f), "--output", str(f / "out"), "--kinds", "drop,drop"], "--kinds must name each kind once", None),
        Case("advperc requirements P.yaml", "`--bins` not increasing", lambda f: ["requirements", _params(f), "--output", str(f / "out"), "--bins", "40,20"], "--bins must be increasing positive radii", None),
        Case("advperc requirements P.yaml", "`--bins` not numbers", lambda f: ["requirements", _params(f), "--output", str(f / "out"), "--bins", "near,far"], "expected comma-separated radii", None),
        Case("advperc requirements P.yaml", "`--typical` -1", lambda f: ["requirements", _params(f), "--output", str(f / "out"), "--typical", "-1"], "--typical must be a number of samples", None),
        Case("advperc requirements P.yaml", "`--iterations` 50", lambda f: ["requirements", _params(f), "--output", str(f / "out"), "--iterations", "50"], "--iterations must be from 0 to 20", None),
        Case("advperc requirements P.yaml", "a params file that sets `requirement.kind` itself", lambda f: ["requirements", _params(f, **{"requirement.kind": "drop"}), "--output", str(f / "out")], "'requirement.kind' is set", "p.yaml"),
        Case("advperc requirements P.yaml", "`--output` a folder of the user's files", lambda f: (f / "mine").mkdir() or (f / "mine" / "notes.txt").write_text("x") and ["requirements", _params(f), "--output", str(f / "mine")], "no requirements run made", "mine"),
        Case("advperc robustness RESULTS", "results folder missing", lambda f: ["robustness", str(f / "none")], "report.json", "none"),
        Case("advperc robustness RESULTS", "report.json not JSON", robustness(report="{garbage"), "report.json", "report.json"),
        Case("advperc robustness RESULTS", "report.json without params", robustness(report={"bag": "x"}), "params", "report.json"),
        Case("advperc robustness RESULTS", "attack_errors.npz not an npz", robustness(errors=b"garbage"), "attack_errors.npz", "attack_errors.npz"),
        Case("advperc robustness RESULTS", "error tensor of another bag", robustness(errors=_npz((3, 2))), "shape", "attack_errors.npz"),
        Case("advperc robustness RESULTS --strengths", "`--strengths abc`", robustness("--strengths", "abc"), "--strengths", None),
        Case("advperc robustness RESULTS --strengths", "`--strengths -0.5`", robustness("--strengths", "-0.5"), "--strengths", None),
        Case("advperc robustness RESULTS --strengths", "`--strengths 1.5`", robustness("--strengths", "0,1.5"), "--strengths", None),
        Case("advperc robustness RESULTS --samples", "`--samples 0`", robustness("--samples", "0"), "--samples", None),
        Case("advperc score GT PERCEIVED", "ground-truth bag missing", lambda f: ["score", str(f / "none"), str(GOOD_BAG)], "none", "none"),
        Case("advperc score GT PERCEIVED", "no detections topic", lambda f: ["score", str(GOOD_BAG), str(GOOD_BAG)], "/perception/objects", None),
        Case("advperc score GT PERCEIVED --errors", "`--errors ghosts`, no such kind", lambda f: ["score", str(GOOD_BAG), str(GOOD_BAG), "--errors", "ghosts"], "--errors", None),
        Case("advperc score GT PERCEIVED --model", "model file missing", lambda f: ["score", str(GOOD_BAG), str(GOOD_BAG), "--model", str(f / "none.json")], "none.json", "none.json"),
        Case("advperc pem fit BAG --output", "input bag missing", lambda f: ["pem", "fit", str(f / "none"), "--output", str(f / "m.json")], "none", "none"),
        Case("advperc pem fit BAG --output", "detections that copy the ground truth (an attack bag's)",
             lambda f: ["pem", "fit", _copied_detections_bag(f), "--output", str(f / "m.json")],
             "detections are their ground truth to the micrometre", "copied"),
        Case("advperc pem fit BAG --output", "output is a folder", lambda f: (f / "m").mkdir() or ["pem", "fit", str(GOOD_BAG), "--output", str(f / "m")], "m", "m"),
        Case("advperc pem fit BAG --output", "output under a file", lambda f: (f / "file").write_text("x") and ["pem", "fit", str(GOOD_BAG), "--output", str(f / "file" / "m.json")], "file", "file"),
        Case("advperc pem fit BAG --output", "output where nothing can be made (`/proc`)", lambda f: ["pem", "fit", str(GOOD_BAG), "--output", "/proc/m.json"], "cannot create the model file", "/proc/m.json"),
        Case("advperc import-commonroad XML", "recording missing", lambda f: ["import-commonroad", str(f / "none.xml")], "none.xml", "none.xml"),
        Case("advperc import-commonroad XML", "recording not XML", lambda f: (f / "r.xml").write_text("<<<") and ["import-commonroad", str(f / "r.xml"), "--output", str(f / "bag")], "r.xml", "r.xml"),
        Case("advperc import-bag LOG", "log missing", lambda f: ["import-bag", str(f / "none")], "no such bag", "none"),
        Case("advperc import-bag LOG", "log without odometry", lambda f: _drive_log(f, odometry=False) + ["--output", str(f / "bag")], "no odometry topic", "log"),
        Case("advperc import-bag LOG --objects", "objects topic of another type", lambda f: _drive_log(f) + ["--objects", "/localization/kinematic_state", "--output", str(f / "bag")], "has type 'nav_msgs/msg/Odometry', not one of", "log"),
        Case("advperc import-bag LOG --dt", "`--dt 1e-12` (rounded to 0 ns: a traceback)", lambda f: _drive_log(f) + ["--dt", "1e-12", "--output", str(f / "bag")], "the frame period --dt must be between", "log"),
        Case("advperc import-bag LOG --dt", "`--dt 1e300` (overflowed: a traceback)", lambda f: _drive_log(f) + ["--dt", "1e300", "--output", str(f / "bag")], "the frame period --dt must be between", "log"),
        Case("advperc import-bag LOG --output", "a 300-byte output name (a traceback)", lambda f: _drive_log(f) + ["--output", str(f / ("x" * 300))], "a name in its path is longer than the file system allows", None),
        Case("advperc import-bag LOG", "no objects topic but the map's `/map/lanes` (imported as objects, 0 agents)", lambda f: _lanes_only_log(f), "no objects topic", "log"),
        Case("advperc import-bag LOG", "log shorter than two frames", lambda f: _drive_log(f, frames=1) + ["--output", str(f / "bag")], "overlap for less than two frames", "log"),
        Case("advperc make-bags SCENARIO", "scenario file missing", lambda f: ["make-bags", str(f / "none.yaml"), "--output-dir", str(f / "bags")], "none.yaml", "none.yaml"),
        Case("advperc make-bags SCENARIO --output-dir", "output folder a file", lambda f: (f / "file").write_text("x") and ["make-bags", str(REPO / "scenarios" / "idm_lane_following.yaml"), "--output-dir", str(f / "file")], "is not a folder", "file"),
        Case("advperc make-bags SCENARIO --output-dir", "output folder a symbolic link to nothing", lambda f: _link(f / "bags", "nowhere") or ["make-bags", str(REPO / "scenarios" / "idm_lane_following.yaml"), "--output-dir", str(f / "bags")], "symbolic link to nothing", "bags"),
        Case("advperc make-bags SCENARIO --force", "`--force` onto a folder of the user's that is not a bag", lambda f: (f / "bags" / "idm_lane_following").mkdir(parents=True) or ["make-bags", str(REPO / "scenarios" / "idm_lane_following.yaml"), "--output-dir", str(f / "bags"), "--force"], "not a rosbag2 bag", "idm_lane_following"),
        Case("advperc campaign FILE", "`thresholds.nds` .nan (a gate that could never fail)", campaign_file(thresholds={"nds": float("nan")}), "field 'thresholds.nds'"),
        Case("advperc campaign FILE", "`thresholds.nds_t` .inf", campaign_file(thresholds={"nds_t": float("inf")}), "field 'thresholds.nds_t'"),
        Case("advperc campaign FILE", "`thresholds.nds` 5.0 (above any score)", campaign_file(thresholds={"nds": 5.0}), "field 'thresholds.nds'"),
        Case("advperc campaign FILE", "`output` a folder of the user's files (it wrote among them and deleted one)", lambda f: (f / "mine").mkdir() or (f / "mine" / ".x.partial").mkdir() or campaign_file(output=str(f / "mine"))(f), "did not make", "c.yaml"),
        Case("advperc campaign FILE", "`ray_address` garbage (Ray ended in a traceback after the output was written)", campaign_file(executor="ray", ray_address="garbage"), "field 'ray_address' must be HOST:PORT"),
        Case("advperc campaign FILE", "`ray_address` ''", campaign_file(executor="ray", ray_address=""), "field 'ray_address' must be HOST:PORT"),
        Case("advperc campaign FILE", "`ray_address` 127.0.0.1:1, where nothing answers (Ray retried for minutes)", campaign_file(executor="ray", ray_address="127.0.0.1:1"), "field 'ray_address' nothing answers at 127.0.0.1:1"),
        Case("advperc campaign FILE", "`ray_address` with `executor: process` (was ignored)", campaign_file(executor="process", ray_address="127.0.0.1:6379"), "field 'ray_address' is for executor ray"),
        Case("advperc campaign FILE", "`baseline` a folder that does not exist", campaign_file(baseline="nowhere"), "field 'baseline' names 'nowhere', which does not exist", "c.yaml"),
        Case("advperc campaign FILE", "`baseline` a folder that is no campaign's output (no summary.json)", lambda f: (f / "old").mkdir() or campaign_file(baseline=str(f / "old"))(f), "field 'baseline' names", "c.yaml"),
        Case("advperc campaign FILE", "`baseline` whose summary names an attack folder that is gone", lambda f: _baseline_without_folders(f) or campaign_file(baseline=str(f / "old"))(f), "field 'baseline' cell p-nds_t-0-idm", "report.json"),
        Case("advperc campaign FILE --output", "output a symbolic link to nothing", lambda f: _link(f / "out", "nowhere") or ["campaign", str(REPO / "examples" / "campaign.yaml"), "--output", str(f / "out")], "is a symbolic link", "out"),
        Case("advperc pem fit BAG --output", "output under a symbolic link loop", lambda f: _link(f / "loop", "loop") or ["pem", "fit", str(GOOD_BAG), "--output", str(f / "loop" / "m.json")], "symbolic link loop", "loop"),
        Case("advperc make-bags SCENARIO", "scenario file a FIFO (it blocked forever)", lambda f: os.mkfifo(f / "s.yaml") or ["make-bags", str(f / "s.yaml"), "--output-dir", str(f / "bags")], "not a regular file", "s.yaml"),
        Case("advperc make-bags SCENARIO", "scenario not YAML", lambda f: (f / "s.yaml").write_text("a: [") and ["make-bags", str(f / "s.yaml"), "--output-dir", str(f / "bags")], "s.yaml", "s.yaml"),
    ]
    return cases


def _copied_detections_bag(folder: Path) -> str:
    """A bag whose /perception/objects are its ground truth's boxes, confidences and all, as an attack bag's are
    but for the attack's errors."""
    from advperc_ros.ros import bag as bags
    from advperc_ros.ros import cdr
    from advperc_ros.ros.topics import PERCEPTION

    scenario = bags.read_scenario(GOOD_BAG)
    with bags.open_bag_for_writing(folder / "copied") as bag:
        bags.write_scenario(bag, scenario)
        for k, ns in enumerate(scenario.stamps_ns):
            detected = {**scenario.agents.frame(k), "score": np.ones(len(scenario.agents.frame(k)["ids"]))}
            bag.write(PERCEPTION, int(ns), cdr.encode_objects(detected, int(ns), "perception"))
    return str(folder / "copied")


def _lanes_only_log(folder: Path) -> list[str]:
    """`import-bag` of a log with the ego's odometry and the map's lanes (a MarkerArray), but no objects."""
    from test_import_bag import BUNDLED, ODOMETRY, write_log

    from advperc_ros.core.scenario import EgoState
    from advperc_ros.ros import messages as msgs
    from advperc_ros.ros.bag import read_topics
    from advperc_ros.ros.topics import LANES

    lanes, _ = read_topics(BUNDLED, [LANES], raw=True)
    odometry = [(k * 100_000_000, msgs.ego_to_cdr(EgoState(0.5 * k, 0.0, 0.0, 5.0), k * 100_000_000)) for k in range(5)]
    topics = {LANES: ("visualization_msgs/msg/MarkerArray", lanes[LANES]), ODOMETRY: ("nav_msgs/msg/Odometry", odometry)}
    return ["import-bag", str(write_log(folder / "log", topics)), "--output", str(folder / "bag")]


def _drive_log(folder: Path, odometry: bool = True, frames: int = 5) -> list[str]:
    """`import-bag` of a small Autoware log in `folder` (objects at rest, the ego driving at 5 m/s)."""
    from test_import_bag import ODOMETRY, OBJECTS, write_log

    from advperc_ros.core.scenario import EgoState
    from advperc_ros.ros import messages as msgs
    from advperc_ros.ros.interfaces import autoware

    one = {"ids": np.array([1]), "x": np.array([30.0]), "y": np.array([0.0]), "yaw": np.array([0.0]), "vx": np.zeros(1),
           "vy": np.zeros(1), "length": np.array([4.5]), "width": np.array([1.8]), "height": np.array([1.5]),
           "score": np.array([np.nan])}
    stamps = [k * 100_000_000 for k in range(frames)]
    topics = {OBJECTS: (autoware.PREDICTED, [(t, autoware.encode_predicted(one, t)) for t in stamps])}
    if odometry:
        topics[ODOMETRY] = ("nav_msgs/msg/Odometry", [(t, msgs.ego_to_cdr(EgoState(0.5 * k, 0.0, 0.0, 5.0), t))
                                                       for k, t in enumerate(stamps)])
    return ["import-bag", str(write_log(folder / "log", topics))]


def campaign_file(**fields) -> Callable[[Path], list[str]]:
    """`advperc campaign` of a small valid campaign file, changed by `fields`."""
    def build(folder: Path) -> list[str]:
        document = {"name": "small", "output": str(folder / "campaign"), "scenarios": [_params(folder)],
                    "objectives": ["nds_t"], "seeds": [0], "executor": "serial", **fields}
        (folder / "c.yaml").write_text(yaml.safe_dump(document))
        return ["campaign", str(folder / "c.yaml"), "--quiet"]
    return build


def _baseline_without_folders(folder: Path) -> None:
    """An earlier campaign's output whose summary says `p-nds_t-0-idm` (the cell of `campaign_file`) found an
    attack, with that cell's folder removed."""
    (folder / "old").mkdir()
    (folder / "old" / "summary.json").write_text(json.dumps({"cells": [{"cell": "p-nds_t-0-idm", "collision": True}]}))


def _disk_with_one_mib_free(monkeypatch: pytest.MonkeyPatch) -> None:
    usage = shutil.disk_usage("/")
    monkeypatch.setattr("advperc_ros.results.destination.shutil.disk_usage", lambda place: type(usage)(10 << 20, 9 << 20, 1 << 20))


def _link(path: Path, target: str) -> None:
    path.symlink_to(target)


def _broken_bag(folder: Path) -> bool:
    (folder / "bag").mkdir()
    (folder / "bag" / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: 9}\n")
    (folder / "bag" / "bag.mcap").write_bytes(b"not an mcap file")
    return True


def _npz(shape: tuple[int, int]) -> bytes:
    import io

    buffer = io.BytesIO()
    np.savez(buffer, dx=np.zeros(shape), dy=np.zeros(shape), dyaw=np.zeros(shape), fn=np.zeros(shape, bool))
    return buffer.getvalue()


CASES = _cases()


def _tree(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


@pytest.mark.parametrize("case", CASES, ids=[f"{c.command.split()[1]}: {c.bad}" for c in CASES])
def test_bad_input_is_one_line_exit_2_nothing_written(case, tmp_path, capsys, monkeypatch):
    folder = tmp_path / "work"
    folder.mkdir()
    monkeypatch.chdir(folder)
    argv = case.argv(folder)
    if case.setup is not None:
        case.setup(monkeypatch)
    before = _tree(folder)
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse refuses flags of the wrong form (one line too: cli.OneLineParser)
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("advperc: error:"), err
    assert case.says in err, err
    named = _first_file(argv) if case.names_file == "?" else case.names_file
    if named is not None:
        assert Path(named).name in err, err
    assert _tree(folder) == before, "something was written"


def _first_file(argv: list[str]) -> str | None:
    return next((a for a in argv[1:] if not a.startswith("-")), None)


def docs_table() -> str:
    rows = ["| command | bad input | the line says |", "|---|---|---|"]
    rows += [f"| `{c.command}` | {c.bad} | `{c.says}` |" for c in CASES]
    return "\n".join(rows)


def test_the_docs_list_every_case(repo):
    page = repo / DOCS_PAGE
    text = page.read_text()
    table = docs_table()
    if os.environ.get("ADVPERC_WRITE_DOCS") == "1":
        start, end = text.index(TABLE_START) + len(TABLE_START), text.index(TABLE_END)
        page.write_text(text[:start] + "\n" + table + "\n" + text[end:])
        text = page.read_text()
    block = text.split(TABLE_START)[1].split(TABLE_END)[0].strip()
    assert block == table, f"{DOCS_PAGE}'s bad-input table is out of date: ADVPERC_WRITE_DOCS=1 rewrites it"
    assert len(CASES) >= 100 and len({(c.command, c.bad) for c in CASES}) == len(CASES)
    assert re.search(rf"{len(CASES)} kinds of bad input", text)
