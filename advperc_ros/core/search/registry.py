"""Search methods by name, imported only when asked for (`core.plugins`, as every plug-in).

Adding a method: a module with a class that has the `method.SearchMethod` protocol, and one line
here. `search.method`'s allowed values (advperc_ros.params) and `advperc attack --method` come
from this table.
"""

from advperc_ros.core.plugins import PluginKind, load
from advperc_ros.core.search.config import SearchConfig
from advperc_ros.core.search.method import SearchMethod
from advperc_ros.core.search.problem import Phase, PhaseLabel

# paper: the paper's Algorithms 1 and 2 and the refine phase; guided: Algorithm 1, then the guided search
METHODS = {
    "paper": "advperc_ros.core.search.paper:PaperMethod",
    "guided": "advperc_ros.core.search.guided:GuidedMethod",
}
SEARCH_METHODS = PluginKind("search method", METHODS, type, "a class", plug_ins=False)


def method_class(name: str) -> type[SearchMethod]:
    """The class of the method `name` (a key of METHODS); a PluginError otherwise."""
    cls: type[SearchMethod] = load(name, SEARCH_METHODS)
    return cls


def search_method(config: SearchConfig) -> SearchMethod:
    """The method `config.method` names, built with `config`."""
    return method_class(config.method)(config)


def every_phase() -> dict[Phase, PhaseLabel]:
    """Every registered method's phases and how to show them: for a log whose method is not known."""
    return {phase: label for method in METHODS for phase, label in method_class(method).phases.items()}
