"""Local Sphinx extension: the params reference rendered from `advperc_ros.params.SCHEMA`.

The `params-table` directive (in docs/params.md) renders `markdown_table()`, so the table of
parameters, their types, defaults, bounds and descriptions cannot drift from the code;
test/test_docs.py checks the same function against the schema.
"""

from docutils.parsers.rst import Directive
from docutils.statemachine import StringList
from docutils import nodes

PLANNER_PARAMS_DESCRIPTION = (
    "keyword arguments of the planner's constructor, `Class(context, **planner_params)` "
    "(each planner's own: IDM, ObP and the reactive adapter list theirs in [Plugging in](plugging-in.md))"
)


def _literal(value) -> str:
    if isinstance(value, bool):
        value = str(value).lower()
    return f"`{value}`"


def _default(param) -> str:
    return "(required)" if param.default is None else _literal(param.default)


def _number(value) -> str:
    if value == 2**63 - 1:
        return "2^63-1 (a ROS int64)"
    return str(int(value)) if float(value).is_integer() and not isinstance(value, float) else f"{value:g}"


def _bounds(param) -> str:
    """What the schema allows beyond the type: choices, or the range of a number."""
    if param.choices:
        return "one of " + ", ".join(_literal(c) for c in param.choices)
    parts = []
    if param.positive:
        parts.append("> 0")
    elif param.low is not None:
        parts.append(f">= {_number(param.low)}")
    if param.high is not None:
        parts.append(f"<= {_number(param.high)}")
    if param.type is float:
        parts.append("finite")
    return ", ".join(parts)


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def markdown_table() -> str:
    """The params reference as a Markdown table, one row per schema name (dotted, as ROS names them)."""
    from advperc_ros.params import PLANNER_PARAMS, SCHEMA

    rows = ["| parameter | type | default | allowed | meaning |", "|---|---|---|---|---|"]
    for name, param in SCHEMA.items():
        rows.append(f"| `{name}` | {param.type.__name__} | {_default(param)} | {_bounds(param)} | {_cell(param.description)} |")
        if name == "planner":  # the free mapping is not a schema field: it goes beside its planner
            rows.append(f"| `{PLANNER_PARAMS}` | mapping | `{{}}` | finite scalars | {PLANNER_PARAMS_DESCRIPTION} |")
    return "\n".join(rows)


class ParamsTable(Directive):
    """```{params-table}``` renders `markdown_table()` as part of the page it sits in."""

    has_content = False

    def run(self):
        container = nodes.container(classes=["params-table"])
        self.state.nested_parse(StringList(markdown_table().splitlines(), source="advperc_ros.params.SCHEMA"),
                                self.content_offset, container)
        return container.children


def setup(app):
    app.add_directive("params-table", ParamsTable)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
