"""Where results go: checked before any work starts, so no long run is lost to an unwritable path."""

import os
import tempfile
from pathlib import Path

from advperc_ros.params import ParamsError


def check_output(output: Path, kind: str = "output folder") -> None:
    """Refuse an output that exists already (a file we may replace is fine, not a folder) or that
    cannot be created and written: one line naming it. A symbolic link is refused whatever it points
    to (a loop, nothing, or a place the user did not name), and so is a name the file system cannot
    hold, so that no run fails on it after its work."""
    longest = max(output.parts, key=lambda part: len(os.fsencode(part)), default="")
    name_max = os.pathconf(output.anchor or ".", "PC_NAME_MAX")
    if len(os.fsencode(longest)) > name_max:  # before any look at the path, which fails on such a name
        raise ParamsError(f"{str(output)[:60]}...: cannot create the {kind}: a name in its path is longer than the "
                          f"file system allows ({name_max} bytes)")
    if output.is_symlink():
        raise ParamsError(f"{output}: the {kind} is a symbolic link; name the place it should be itself")
    try:
        output.resolve()
    except (RuntimeError, OSError):  # Python 3.11 and 3.12 raise RuntimeError on a loop, 3.13 OSError
        raise ParamsError(f"{output}: cannot create the {kind}: its path runs through a symbolic link loop") from None
    if output.exists() and (kind.endswith("folder") or output.is_dir()):
        raise ParamsError(f"{output}: {kind} exists already; choose another")
    parent = output.parent
    while not parent.exists():
        if parent.is_symlink():
            raise ParamsError(f"{output}: cannot create the {kind}: {parent} is a symbolic link to nothing")
        parent = parent.parent
    if not parent.is_dir():
        raise ParamsError(f"{output}: cannot create the {kind}: {parent} is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ParamsError(f"{output}: cannot create the {kind}: {parent} is not writable")
    try:  # root passes access() everywhere: only making something there proves it (/proc, read-only mounts)
        os.rmdir(tempfile.mkdtemp(prefix=".advperc-probe-", dir=parent))
    except OSError as exc:
        raise ParamsError(f"{output}: cannot create the {kind} in {parent}: {exc.strerror}") from None
