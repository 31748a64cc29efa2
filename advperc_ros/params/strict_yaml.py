"""Params files read strictly: YAML with no key given twice and no recursive alias, any failure one
line naming the file."""

from pathlib import Path
from typing import Any

import yaml

from advperc_ros.core.inputs import read_input_text
from advperc_ros.exceptions import ParamsError
from advperc_ros.params.schema import AttackParams
from advperc_ros.params.tree import parse_params


class _StrictLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a key given twice in one mapping (PyYAML keeps the last silently,
    so a second `seed:` further down overrode the first without a word)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: set = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            if key in seen:
                raise yaml.constructor.ConstructorError(None, None, f"key {key!r} given twice", key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep)


def _refuse_cycles(value: Any, path: Path, kind: str, inside: frozenset[int] = frozenset()) -> None:
    """A YAML anchor an alias refers to from within itself makes a structure that contains itself,
    which every later walk of it recursed into without end."""
    if isinstance(value, (dict, list)):
        if id(value) in inside:
            raise ParamsError(f"{path}: cannot read {kind}: an anchor refers to itself (a recursive alias)")
        for item in value.values() if isinstance(value, dict) else value:
            _refuse_cycles(item, path, kind, inside | {id(value)})


def read_yaml(path: Path, kind: str) -> Any:
    """A YAML document, or one line naming the file: missing, not a regular file (a FIFO would block, a
    device never end), too large, unreadable, not UTF-8, not YAML, a key twice or a recursive alias."""
    try:
        document = yaml.load(read_input_text(path), Loader=_StrictLoader)
    except FileNotFoundError:
        raise ParamsError(f"{path}: no such {kind}") from None
    except OSError as exc:  # not a regular file, too large, unreadable
        raise ParamsError(f"{path}: cannot read {kind}: {exc.strerror}") from None
    except (UnicodeDecodeError, yaml.YAMLError, RecursionError) as exc:
        raise ParamsError(f"{path}: cannot read {kind}: {exc}".replace("\n", " ")) from exc
    _refuse_cycles(document, path, kind)
    return document


def load_params(path: str | Path) -> AttackParams:
    path = Path(path)
    return parse_params(read_yaml(path, "params file"), str(path), path)
