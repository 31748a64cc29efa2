"""Reading a user's input file whole, by one rule for every reader: only a regular file is read (a
FIFO would block the command forever, a device such as /dev/zero never end), and only up to a size
no input of this tool comes near, so that a wrong path is one line, not a hang or a MemoryError.

The failures are `OSError`s with the reason as their `strerror`, which every reader already turns
into its own one-line error naming the file."""

import errno
from pathlib import Path

INPUT_MAX_BYTES = 16 * 1024 * 1024  # a params, campaign, scenario or model file is kilobytes


def read_input(path: Path, max_bytes: int = INPUT_MAX_BYTES) -> bytes:
    """The bytes of the regular file `path` (FileNotFoundError when there is none)."""
    path = Path(path)
    if path.exists() and not path.is_file():
        raise OSError(errno.EINVAL, "not a regular file (a FIFO would block, a device never end)", str(path))
    with path.open("rb") as handle:
        data = handle.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise OSError(errno.EFBIG, f"larger than {max_bytes // 2**20} MiB", str(path))
    return data


def read_input_text(path: Path, max_bytes: int = INPUT_MAX_BYTES) -> str:
    """`read_input` as UTF-8 text (UnicodeDecodeError when it is not)."""
    return read_input(path, max_bytes).decode("utf-8")
