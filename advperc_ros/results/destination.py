"""Where results go: checked before any work starts, so no long run is lost to an unwritable path,
and held by one run at a time, so two runs never write the same place."""

import errno
import fcntl
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from advperc_ros.exceptions import OutOfSpace, OutputError

MIB = 1 << 20
FULL = (errno.ENOSPC, errno.EDQUOT)  # a full disk, and a full quota: the same to the user


def check_output(output: Path, kind: str = "output folder") -> None:
    """Refuse an output that exists already (a file we may replace is fine, not a folder) or that
    cannot be created and written: one line naming it. A symbolic link is refused whatever it points
    to (a loop, nothing, or a place the user did not name), and so is a name the file system cannot
    hold, so that no run fails on it after its work."""
    longest = max(output.parts, key=lambda part: len(os.fsencode(part)), default="")
    name_max = os.pathconf(output.anchor or ".", "PC_NAME_MAX")
    if len(os.fsencode(longest)) > name_max:  # before any look at the path, which fails on such a name
        raise OutputError(f"{str(output)[:60]}...: cannot create the {kind}: a name in its path is longer than the "
                          f"file system allows ({name_max} bytes)")
    if output.name in ("", ".."):  # '..' names a folder that exists (or will, once the ones before it are made)
        raise OutputError(f"{output}: the {kind} must be named by its own name, not by '..' or a root")
    for climb in (index for index, part in enumerate(output.parts) if part == ".."):
        before = Path(*output.parts[:climb])
        if not before.is_dir():  # the writer's making of `before` would make the output's name before it
            raise OutputError(f"{output}: the {kind}'s path climbs with '..' out of {before}, which is not a folder "
                              f"yet; name the place without '..'")
    if output.is_symlink():
        raise OutputError(f"{output}: the {kind} is a symbolic link; name the place it should be itself")
    try:
        output.resolve()
    except (RuntimeError, OSError):  # Python 3.11 and 3.12 raise RuntimeError on a loop, 3.13 OSError
        raise OutputError(f"{output}: cannot create the {kind}: its path runs through a symbolic link loop") from None
    if output.exists() and (kind.endswith("folder") or output.is_dir()):
        raise OutputError(f"{output}: {kind} exists already; choose another")
    parent = output.parent
    while not parent.exists():
        if parent.is_symlink():
            raise OutputError(f"{output}: cannot create the {kind}: {parent} is a symbolic link to nothing")
        parent = parent.parent
    if not parent.is_dir():
        raise OutputError(f"{output}: cannot create the {kind}: {parent} is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"{output}: cannot create the {kind}: {parent} is not writable")
    try:  # root passes access() everywhere: only making something there proves it (/proc, read-only mounts)
        os.rmdir(tempfile.mkdtemp(prefix=".advperc-probe-", dir=parent))
    except OSError as exc:
        raise OutputError(f"{output}: cannot create the {kind} in {parent}: {exc.strerror}") from None


def _existing(path: Path) -> Path:
    """`path` or its nearest ancestor that exists: where the file system's free space is asked."""
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def check_free_space(output: Path, needed_bytes: int, kind: str = "output folder") -> None:
    """Refuse a run whose output (an estimate from the caller, generous rather than tight) does not
    fit the free space where it goes: better one line now than a full disk after hours of search."""
    place = _existing(output.parent)
    free = shutil.disk_usage(place).free
    if free < needed_bytes:
        raise OutOfSpace(f"{output}: the {kind} needs about {needed_bytes / MIB:.1f} MiB and {place} has "
                         f"{free / MIB:.1f} MiB free: free some space or choose another place")


@contextmanager
def full_disk_said(output: Path, then: str) -> Iterator[None]:
    """A disk that fills during the block (ENOSPC, EDQUOT) as one OutOfSpace line naming the output
    and saying what to do `then`; any other OSError stays the bug it is."""
    try:
        yield
    except OSError as exc:
        if exc.errno not in FULL:
            raise
        raise OutOfSpace(f"{output}: the disk filled while writing ({exc.strerror}): {then}") from None


@contextmanager
def exclusive(lock: Path, busy: str) -> Iterator[None]:
    """Hold the file `lock` (made if need be) for this run alone while the block runs, else a
    OutputError saying `busy`. An flock, so the kernel releases it however the run ends (SIGKILL
    too) and a killed run never blocks the next. The file goes when the block ends; a run that
    opened it just before finds, once it holds its lock, that the name no longer leads to the file
    it locked, and opens the name again."""
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
        except OSError as exc:
            raise OutputError(f"{lock}: cannot make the lock file: {exc.strerror}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise OutputError(busy) from None
        if _names(lock, fd):
            break
        os.close(fd)  # the lock of a file its last holder removed: it guards nothing
    try:
        yield
    finally:
        lock.unlink(missing_ok=True)  # before the lock goes, so a waiting run sees the file is gone
        os.close(fd)


def _names(path: Path, fd: int) -> bool:
    """Whether `path` still leads to the open file `fd`."""
    try:
        found = os.stat(path, follow_symlinks=False)
    except FileNotFoundError:
        return False
    held = os.fstat(fd)
    return (found.st_dev, found.st_ino) == (held.st_dev, held.st_ino)
