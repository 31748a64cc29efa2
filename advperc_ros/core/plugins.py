"""One loader for every plug-in named by `module:Class` (or `module:attribute`): planners, search
methods, interface profiles, backends.

A registry is a `PluginKind`: what its plug-ins are called in a message, its bundled names (each
a `module:attribute` imported only when asked for, so naming the choices imports no implementation)
and what a loaded object must be. `load` refuses, with one `PluginError` line naming the plug-in,
an unknown name, a module that cannot be imported or raises as it runs, a missing attribute and an
object of the wrong kind; adding a bundled plug-in is one line of its registry.
"""

import importlib
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from advperc_ros.exceptions import PluginError


@dataclass(frozen=True)
class PluginKind:
    """A registry of one kind of plug-in: `what` names it in messages ("planner"), `bundled` maps
    each bundled name to its `module:attribute`, and a loaded object must be an instance of
    `expected` (`type`: a class), described as `expected_text` when it is not."""

    what: str
    bundled: Mapping[str, str]
    expected: type
    expected_text: str
    plug_ins: bool = True  # a `module:attribute` outside the bundled names is taken too

    def names(self) -> tuple[str, ...]:
        return tuple(self.bundled)


def one_line(exc: BaseException) -> str:
    """The exception's message on one line: the CLI reports a refused input as one line."""
    return " ".join(str(exc).split())


def load(target: str, kind: PluginKind) -> Any:
    """The object `target` names: a bundled name of `kind`, or (when it takes plug-ins) `module:attribute`."""
    if target in kind.bundled:
        path = kind.bundled[target]
    elif kind.plug_ins and ":" in target:
        path = target
    else:
        plug_in = "; or module:Class" if kind.plug_ins else ""
        raise PluginError(f"unknown {kind.what} '{target}' ({kind.what}s: {', '.join(kind.bundled)}{plug_in})")
    module_name, _, attribute = path.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise PluginError(f"{kind.what} '{target}' cannot be imported: {one_line(exc)}") from exc
    except (Exception, SystemExit) as exc:  # its module fails as it runs: a bug of the plug-in, said in one line
        raise PluginError(f"{kind.what} '{target}': importing {module_name} raised {type(exc).__name__}: "
                          f"{one_line(exc)}") from exc
    if not hasattr(module, attribute):
        raise PluginError(f"{kind.what} '{target}' cannot be imported: module '{module_name}' has no attribute "
                          f"'{attribute}'")
    loaded = getattr(module, attribute)
    if not isinstance(loaded, kind.expected):
        raise PluginError(f"{kind.what} '{target}' is a {type(loaded).__name__}, not {kind.expected_text}")
    return loaded
