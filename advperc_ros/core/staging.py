"""Folders written atomically: everything goes into a hidden `.<name>.partial` beside the target,
renamed into place only when complete, so a killed or failed write never leaves a folder that looks
finished (and the next run clears what it left)."""

import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def staging_path(path: Path) -> Path:
    """The hidden sibling a folder or file is written to before it is renamed into place."""
    return path.with_name(f".{path.name}.partial")


@contextmanager
def staged_folder(path: Path) -> Iterator[Path]:
    """Yields the staging path (cleared, its parent made; the folder itself is the caller's to
    create, as some writers insist on making it); renames it to `path` when the block ends without
    an error, removes it when the block raises."""
    staging = staging_path(Path(path))
    if staging.exists():
        shutil.rmtree(staging)
    staging.parent.mkdir(parents=True, exist_ok=True)
    try:
        yield staging
        staging.rename(path)
    finally:
        if staging.exists():
            shutil.rmtree(staging)
