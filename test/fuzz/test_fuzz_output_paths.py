"""Fuzzing the output gate every command passes (`results.destination.check_output`) with paths a clumsy or hostile
user gives: made of folders, files, FIFOs, symbolic links (to nothing, to themselves, in a loop of
two, to a folder, to a file), names over 255 bytes, `.`, `..` and names still to be made. Either the
gate refuses in one line naming the path, having changed nothing, or a folder (or, for a file output,
a file) can really be made there: no command that passed the gate fails on its output after its work."""

import os
import shutil
from pathlib import Path

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from mutations import one_line_naming

from advperc_ros.exceptions import OutputError
from advperc_ros.results.destination import check_output

FUZZ = settings(max_examples=300, deadline=5000, suppress_health_check=list(HealthCheck))  # deadline: hang guard
KINDS = ("folder", "file", "fifo", "link to nothing", "link to itself", "loop of two", "link to folder",
         "link to file", "missing")
NAMES = st.sampled_from(["a", "b", "out", ".", "..", "o" * 256, "é", "with space"])


def _make(place: Path, kind: str) -> None:
    """`place` as an entry of that kind (its parent exists)."""
    if kind == "folder":
        place.mkdir()
    elif kind == "file":
        place.write_text("the user's")
    elif kind == "fifo":
        os.mkfifo(place)
    elif kind == "link to nothing":
        place.symlink_to("nowhere")
    elif kind == "link to itself":
        place.symlink_to(place.name)
    elif kind == "loop of two":
        place.symlink_to(f"{place.name}.twin")
        place.with_name(f"{place.name}.twin").symlink_to(place.name)
    elif kind == "link to folder":
        (place.parent / "target").mkdir(exist_ok=True)
        place.symlink_to("target")
    elif kind == "link to file":
        (place.parent / "target.txt").write_text("x")
        place.symlink_to("target.txt")


def _tree(root: Path) -> dict[str, tuple]:
    """Every entry under root with what it is (no link followed); a folder's times are left out, as
    the gate's probe (a folder made and removed in the parent) touches them and nothing else."""
    seen = {}
    for folder, dirs, files in os.walk(root):
        for name in dirs + files:
            entry = Path(folder) / name
            info = entry.lstat()
            seen[str(entry.relative_to(root))] = (info.st_mode, info.st_size, os.readlink(entry) if entry.is_symlink()
                                                  else None if entry.is_dir() else info.st_mtime_ns)
    return seen


@given(steps=st.lists(st.tuples(NAMES, st.sampled_from(KINDS)), min_size=1, max_size=4),
       kind=st.sampled_from(["output folder", "bag folder", "model file"]))
@example(steps=[("a", "missing"), ("..", "folder"), ("a", "folder")], kind="output folder")  # a/../a, a missing:
@example(steps=[("a", "missing"), ("..", "folder"), ("a", "folder")], kind="model file")  # making a/ made a/../a
@FUZZ
def test_the_gate_refuses_in_one_line_or_the_output_can_be_made(steps, kind, tmp_path_factory):
    root = tmp_path_factory.mktemp("gate")
    path = root.joinpath(*"1234")  # as deep as the steps go: a path of '..'s stays inside root
    path.mkdir(parents=True)
    for name, entry in steps:  # each step names an entry under the last; it is made where that can be
        path = path / name
        try:
            if name != ".." and path.parent.is_dir() and not path.parent.is_symlink() and not os.path.lexists(path):
                _make(path, entry)
        except OSError:  # a name the file system refuses: the path keeps it, the gate must refuse it
            pass
    before = _tree(root)
    try:
        check_output(path, kind)
    except OutputError as exc:
        one_line_naming(exc)
        assert str(exc).startswith(str(path)[:60]), (str(path), str(exc))
        assert _tree(root) == before, "the gate changed something"
        return
    finally:
        assert _tree(root) == before, "the gate changed something"
    path.parent.mkdir(parents=True, exist_ok=True)  # what every writer does: the folders still to be made
    if kind.endswith("folder"):
        path.mkdir()
        (path / "report.json").write_text("{}")
    else:
        staging = path.with_name(f".{path.name}.partial")
        staging.write_text("{}")
        staging.rename(path)
        assert path.read_text() == "{}"
    shutil.rmtree(root)  # links included, none followed (pytest's own clean-up trips on loops)
