"""Where results go: checked before any work starts, so no long run is lost to an unwritable path."""

import os
import tempfile
from pathlib import Path

from advperc_ros.params import ParamsError


def check_output(output: Path, kind: str = "output folder") -> None:
    """Refuse an output that exists already (a file we may replace is fine, not a folder) or that
    cannot be created and written: one line naming it."""
    if output.exists() and (kind.endswith("folder") or output.is_dir()):
        raise ParamsError(f"{output}: {kind} exists already; choose another")
    parent = output.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ParamsError(f"{output}: cannot create the {kind}: {parent} is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ParamsError(f"{output}: cannot create the {kind}: {parent} is not writable")
    try:  # root passes access() everywhere: only making something there proves it (/proc, read-only mounts)
        os.rmdir(tempfile.mkdtemp(prefix=".advperc-probe-", dir=parent))
    except OSError as exc:
        raise ParamsError(f"{output}: cannot create the {kind} in {parent}: {exc.strerror}") from None
