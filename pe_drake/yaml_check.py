"""The one reader of YAML files onto dataclasses (:func:`load_yaml_typed`), with a check first.

Drake's ``yaml_load_typed`` answers a misplaced list with a bare ``AssertionError`` and names no
line. So the YAML node tree (which keeps line numbers) is walked beside the dataclass fields
first, refusing with file, line and dotted key: syntax errors, unknown keys, wrong shapes and
types, and what no config holds (deep nesting, Python tags, huge files or alias expansions).
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from pathlib import Path
from typing import Any

from pe_drake import limits
from pe_drake.exceptions import ConfigError, shorten

_NULLS = ("null", "Null", "NULL", "~", "")
_BOOLS = ("true", "True", "TRUE", "false", "False", "FALSE")
#: Deepest nesting of lists and mappings accepted; the deepest config key is 4 levels down.
MAX_NESTING = 100
#: Largest YAML file read [bytes] (PyYAML's pure-Python scanner takes seconds per 10 MB).
MAX_YAML_BYTES = 1024 * 1024
_PYTHON_TAG = "tag:yaml.org,2002:python/"
#: Most values a YAML file may hold once its aliases are expanded (the loader and the schema
#: walk expand them: ten nested anchors of ten aliases are 10¹⁰ values).
MAX_EXPANDED_NODES = 100_000


def _where(source: str, node, key: str) -> str:
    line = f"line {node.start_mark.line + 1}, " if node is not None else ""
    return f"{source}: {line}key '{key or '(top level)'}'"


def _strip_optional(tp):
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return (args[0] if len(args) == 1 else tp), True
    return tp, False


def _check_scalar(node, tp, optional: bool, source: str, key: str) -> None:
    import yaml

    if not isinstance(node, yaml.ScalarNode):
        raise ConfigError(f"{_where(source, node, key)}: expected {_kind(tp)}, got {_shape(node)}")
    value = node.value
    if optional and node.tag.endswith(":null") or (optional and value in _NULLS and node.style is None):
        return
    ok = True
    if tp is str and node.style is None and not node.tag.endswith(":str"):
        # YAML reads an unquoted true, yes, on, 1 or null as another type, which Drake refuses
        # with a Python type name: say what to write instead.
        kind = node.tag.rsplit(":", 1)[-1]
        raise ConfigError(f"{_where(source, node, key)}: expected a string, got '{shorten(value)}', "
                          f"which YAML reads as {'an' if kind[0] in 'aeiou' else 'a'} {kind}: "
                          f"write it in quotes, \"{shorten(value)}\"")
    if tp is bool:
        ok = value in _BOOLS
    elif tp is int:
        try:
            int(value)
        except ValueError:
            ok = False
    elif tp is float:
        try:
            float(value)
        except ValueError:
            ok = value in (".nan", ".inf", "-.inf", ".NaN", ".Inf", "-.Inf")
    if not ok:
        raise ConfigError(f"{_where(source, node, key)}: expected {_kind(tp)}, got '{shorten(value)}'")


def _kind(tp) -> str:
    tp, _ = _strip_optional(tp)
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp) or isinstance(tp, dict) or origin is dict:
        return "a mapping"
    if origin is list:
        return "a list"
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(tp, str(tp))


def _check_node(node, tp, source: str, key: str) -> None:
    import yaml

    tp, optional = _strip_optional(tp)
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp) or isinstance(tp, dict):  # a dict: {key: type} of a section
        if not isinstance(node, yaml.MappingNode):
            # A whole file that is one scalar is not YAML of ours (a key, a password file named
            # by mistake or on purpose): its content is not echoed.
            got = _shape(node) if key or not isinstance(node, yaml.ScalarNode) else "text that is not YAML keys"
            raise ConfigError(f"{_where(source, node, key)}: expected a mapping of "
                              f"{getattr(tp, '__name__', key.rsplit('.', 1)[-1] or 'top-level')} keys, got {got}")
        hints = tp if isinstance(tp, dict) else typing.get_type_hints(tp)
        for k_node, v_node in node.value:
            name = k_node.value
            sub = f"{key}.{shorten(name)}" if key else shorten(name)
            if name not in hints:
                raise ConfigError(
                    f"{_where(source, k_node, sub)}: unknown key; valid keys here: {', '.join(sorted(hints))}"
                )
            _check_node(v_node, hints[name], source, sub)
    elif origin is list:
        if optional and isinstance(node, yaml.ScalarNode) and node.value in _NULLS:
            return
        if not isinstance(node, yaml.SequenceNode):
            raise ConfigError(f"{_where(source, node, key)}: expected a list, got {_shape(node)}")
        (item,) = typing.get_args(tp)
        for k, child in enumerate(node.value):
            _check_node(child, item, source, f"{key}[{k}]")
    elif origin is dict:
        if not isinstance(node, yaml.MappingNode):
            raise ConfigError(f"{_where(source, node, key)}: expected a mapping, got {_shape(node)}")
        _, value_type = typing.get_args(tp)
        for k_node, v_node in node.value:
            _check_node(v_node, value_type, source, f"{key}['{shorten(k_node.value)}']")
    elif tp in (bool, int, float, str):
        _check_scalar(node, tp, optional, source, key)


def _shape(node) -> str:
    import yaml

    if isinstance(node, yaml.SequenceNode):
        return "a list"
    if isinstance(node, yaml.MappingNode):
        return "a mapping"
    return f"'{shorten(node.value)}'"


def check_yaml_file(path: str | Path, schema: type, what: str = "config") -> None:
    """Refuses a YAML file whose syntax or shape does not fit ``schema``.

    Args:
        path: the file.
        schema: the dataclass it maps onto, or a {key: type} dict (a section without a class).
        what: what the file is, for messages ("config", "truth", "capsule").

    Raises:
        ConfigError: naming the file, the line and the dotted key.
    """
    import yaml  # PyYAML, a dependency of pydrake.common.yaml; lazy like pydrake

    path = Path(path)
    source = f"{what} file '{path}' does not match the {what} format"
    size = path.stat().st_size
    if size > MAX_YAML_BYTES:
        raise ConfigError(f"{what} file '{path}' is {size / 1e6:.1f} MB; a {what} file is a few kB "
                          f"(at most {MAX_YAML_BYTES // 1024 ** 2} MB is read)")
    try:
        root = yaml.compose(path.read_text(errors="replace"), Loader=yaml.SafeLoader)
    except yaml.MarkedYAMLError as err:
        mark = err.problem_mark or err.context_mark
        line = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        raise ConfigError(f"{source}: {line}YAML syntax error: {err.problem or err}") from None
    except yaml.YAMLError as err:
        raise ConfigError(f"{source}: YAML syntax error: {err}") from None
    except RecursionError:
        raise ConfigError(f"{source}: nested too deeply (more than {MAX_NESTING} levels of lists or mappings)") from None
    if root is None:
        return
    check_nodes(root, source)
    _check_node(root, schema, source, "")


def check_nodes(root, source: str) -> None:
    """Refuses nesting deeper than :data:`MAX_NESTING`, tags that build Python objects, a key
    given twice in one mapping (the loader keeps the last silently) and aliases that expand to
    more than :data:`MAX_EXPANDED_NODES` values.

    Walks with a stack (recursion fails on deep nesting), each node once (an alias is its
    anchor's node object), so the walk is linear in the file's size.

    Raises:
        ConfigError: naming ``source``, the line and column, and the tag or key.
    """
    import yaml

    stack = [(root, 1)]
    seen: set[int] = set()
    while stack:
        node, depth = stack.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        mark = node.start_mark
        at = f"line {mark.line + 1}, column {mark.column + 1}"
        if node.tag.startswith(_PYTHON_TAG):
            tag = "!!" + node.tag.removeprefix("tag:yaml.org,2002:")
            raise ConfigError(f"{source}: {at}: tag '{shorten(tag)}': YAML tags that build Python objects are not accepted")
        if depth > MAX_NESTING:
            raise ConfigError(f"{source}: {at}: nested too deeply (more than {MAX_NESTING} levels of lists or mappings)")
        if isinstance(node, yaml.SequenceNode):
            stack += [(child, depth + 1) for child in node.value]
        elif isinstance(node, yaml.MappingNode):
            _check_unique_keys(node, source)
            stack += [(n, depth + 1) for pair in node.value for n in pair]
    expanded = _expanded_size(root)
    if expanded == math.inf:
        raise ConfigError(f"{source}: an alias (*name) stands for a list or mapping that contains it: "
                          "a cycle, which no config holds")
    if expanded > MAX_EXPANDED_NODES:
        raise ConfigError(f"{source}: its aliases (*name) expand to {expanded:.3g} values; a {source.split()[0]} "
                          f"file holds a few hundred (at most {MAX_EXPANDED_NODES} are read)")


def _check_unique_keys(node, source: str) -> None:
    first: dict[str, int] = {}
    for key, _ in node.value:
        if not hasattr(key, "value") or not isinstance(key.value, str) or key.value == "<<":
            continue
        line = key.start_mark.line + 1
        if key.value in first:
            raise ConfigError(f"{source}: line {line}: key '{shorten(key.value)}' is given twice in one mapping "
                              f"(first on line {first[key.value]}); the second would silently replace the first")
        first[key.value] = line


def _expanded_size(root) -> float:
    """How many nodes the tree has once every alias is expanded, in one pass over the distinct
    nodes (sizes of shared nodes memoised; children before parents)."""
    import yaml

    size: dict[int, float] = {}
    started: set[int] = set()
    stack = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        if id(node) in size:
            continue
        children = (node.value if isinstance(node, yaml.SequenceNode)
                    else [n for pair in node.value for n in pair] if isinstance(node, yaml.MappingNode) else [])
        if children_done:
            size[id(node)] = 1.0 + sum(size[id(c)] for c in children)
        elif id(node) in started:  # reached again from inside itself: an alias to its own ancestor
            return math.inf
        else:
            started.add(id(node))
            stack.append((node, True))
            stack += [(c, False) for c in children if id(c) not in size]
    return size[id(root)]


def key_line(path: str | Path, dotted_key: str) -> int | None:
    """The 1-based line of ``dotted_key`` (e.g. "excitation.criterion") in a YAML file, or
    None when the file does not set it (or does not parse)."""
    import yaml

    try:
        node = yaml.compose(Path(path).read_text(errors="replace"), Loader=yaml.SafeLoader)
    except (OSError, yaml.YAMLError, RecursionError):
        return None
    for part in dotted_key.split("."):
        if not isinstance(node, yaml.MappingNode):
            return None
        match = [(k, v) for k, v in node.value if getattr(k, "value", None) == part]
        if not match:
            return None
        key_node, node = match[0]
    return key_node.start_mark.line + 1


def load_yaml_typed(path: str | Path, schema: type, defaults: Any = None, what: str = "config") -> Any:
    """Reads a YAML file onto ``defaults`` (None: ``schema()``) with Drake's ``yaml_load_typed``,
    not validated further; ConfigError for a missing file or one that does not fit ``schema``."""
    import yaml  # lazy, with pydrake: keeps `import pe_drake` light
    from pydrake.common.yaml import yaml_load_typed

    path = Path(path)
    problem = limits.input_file_problem(path)
    if problem:
        raise ConfigError(f"{what} file '{path}' {problem}")
    check_yaml_file(path, schema, what)
    try:
        return yaml_load_typed(schema=schema, filename=str(path),
                               defaults=defaults if defaults is not None else schema())
    except (yaml.YAMLError, RuntimeError, ValueError, TypeError, AttributeError, AssertionError) as err:
        # Drake asserts on a list where it expects a mapping (and vice versa).
        raise ConfigError(f"{what} file '{path}' does not match the {what} format: {shorten(err, 1000)}") from err
