"""Where a params file's bag is: as given, beside the params file, or in the installed package's share."""

import sys
from pathlib import Path

from advperc_ros.exceptions import ParamsError
from advperc_ros.params.schema import AttackParams

PACKAGE = "advperc_ros"


def package_share() -> Path:
    """Where this package's shared files (bags/, config/, launch/) are installed: ament_index knows
    a colcon or ROS install; a plain pip install puts them under Python's prefix; an editable one
    (`pip install -e .`) installs none and runs from its source tree, which holds them."""
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError:
        pass
    else:
        try:
            return Path(get_package_share_directory(PACKAGE))
        except (PackageNotFoundError, OSError):  # not in the index; or no ROS environment sourced
            pass
    installed = Path(sys.prefix) / "share" / PACKAGE
    source_tree = Path(__file__).resolve().parents[2]
    if not installed.is_dir() and (source_tree / "package.xml").is_file():
        return source_tree
    return installed


def find_bag(bag: str, source: Path | None) -> Path:
    """The bag a params file names, in one order for every way of running: as given (absolute, or
    relative to the working directory), relative to the params file `source`, then in the package
    share (`package_share`)."""
    name = Path(bag)
    candidates = [name]
    if not name.is_absolute():
        if source is not None:
            candidates.append(source.parent / name)
        candidates.append(package_share() / name)
    for candidate in candidates:
        if candidate.exists():
            return candidate
    tried = ", ".join(str(c) for c in candidates)
    raise ParamsError(f"{source or 'params'}: parameter 'bag' names '{name}', which does not exist (tried {tried})")


def resolve_bag(params: AttackParams) -> Path:
    """The bag named in the params, found by `find_bag`."""
    return find_bag(params.bag, params.source)
