"""YAML text -> Python data within fixed bounds, by the YAML 1.2 core schema.

PyYAML's ``safe_load`` alone follows aliases into structures of exponential
size (a dozen lines of "billion laughs" take tens of seconds and end in
MemoryError when the value is printed), recurses once per nesting level
(RecursionError at a few thousand), turns a 5,000-digit integer into a
ValueError, keeps the last of two equal keys without a word, and reads
scalars by YAML 1.1: ``1e-6`` is a string (1.1 floats need a dot), ``yes``,
``no``, ``on`` and ``off`` are booleans, ``012`` is octal ten and ``1:30``
is ninety. :func:`parse_yaml`:

1. walks the parser's event stream first (PyYAML's parser is iterative, its
   composer is not) and refuses nesting deeper than :data:`MAX_DEPTH`, more
   than :data:`MAX_NODES` nodes, or a scalar longer than
   :data:`MAX_SCALAR_CHARS`;
2. composes the node graph and refuses an alias that makes it recursive or
   expands it past :data:`MAX_EXPANDED_NODES` nodes in all;
3. resolves plain scalars by the YAML 1.2 core schema: ``null``/``~``/empty,
   ``true``/``false``, integers (decimal, ``0o17``, ``0x1F``; at most
   :data:`MAX_DIGITS` digits), floats (``1e-6``, ``.5``, ``2.``, ``.inf``,
   ``.nan``); everything else is a string;
4. builds only null, booleans, numbers, strings, lists and mappings (an
   explicit tag such as ``!!timestamp`` or ``!!python/object`` is refused),
   with no key twice in one mapping (``<<`` merge keys are honoured).

Every refusal is a :class:`YamlError` whose message is one line saying
where (line and column), what was found and what was expected.
"""

from __future__ import annotations

import re

import yaml
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

__all__ = ["YamlError", "parse_yaml", "MAX_DEPTH", "MAX_NODES", "MAX_EXPANDED_NODES",
           "MAX_SCALAR_CHARS", "MAX_DIGITS"]

MAX_DEPTH = 16                 # nested mappings/sequences; a configuration needs 3
MAX_NODES = 20_000             # nodes written in the text
MAX_EXPANDED_NODES = 100_000   # nodes once every alias is expanded
MAX_SCALAR_CHARS = 4096        # one scalar (PATH_MAX is 4096 on Linux)
MAX_DIGITS = 30                # digits of an integer (2**64 has 20)

_TAG = "tag:yaml.org,2002:"
_INT_RE = re.compile(r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$")
_FLOAT_RE = re.compile(r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
                       r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$")
_BOOL_RE = re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$")
_NULL_RE = re.compile(r"^(?:~|null|Null|NULL|)$")


class YamlError(ValueError):
    """YAML that is refused; the message is one line (where, found, expected)."""


def _clip(text: str, limit: int = 80) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _where(mark) -> str:
    return f"at line {mark.line + 1}, column {mark.column + 1}" if mark else "somewhere"


class _Loader(yaml.SafeLoader):
    """SafeLoader with the YAML 1.2 core schema and duplicate keys refused."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, MappingNode):
            seen: dict[tuple, object] = {}
            for key_node, _ in node.value:
                if not isinstance(key_node, ScalarNode) or key_node.tag == _TAG + "merge":
                    continue
                key = (key_node.tag, key_node.value)
                if key in seen:
                    raise YamlError(f"(YAML) {_where(key_node.start_mark)}: found the key "
                                    f"{_clip(repr(key_node.value), 40)} a second time (first "
                                    f"{_where(seen[key])}), expected each key once")
                seen[key] = key_node.start_mark
        return super().construct_mapping(node, deep=deep)


def _scalar_error(node: ScalarNode, expected: str) -> YamlError:
    return YamlError(f"(YAML) {_where(node.start_mark)}: found {_clip(repr(node.value), 40)} "
                     f"tagged {node.tag.removeprefix(_TAG)}, expected {expected}")


def _construct_int(loader: _Loader, node: ScalarNode) -> int:
    text = loader.construct_scalar(node)
    if not _INT_RE.match(text):
        raise _scalar_error(node, "an integer")
    digits = text.lstrip("+-")
    if len(digits) > MAX_DIGITS:
        raise YamlError(f"(YAML) {_where(node.start_mark)}: found an integer of {len(digits)} "
                        f"digits, expected at most {MAX_DIGITS}")
    if text.startswith("0o"):
        return int(text[2:], 8)
    if text.startswith("0x"):
        return int(text[2:], 16)
    return int(text, 10)


def _construct_float(loader: _Loader, node: ScalarNode) -> float:
    text = loader.construct_scalar(node)
    if not (_FLOAT_RE.match(text) or _INT_RE.match(text)):
        raise _scalar_error(node, "a number")
    lowered = text.lower()
    if lowered.endswith(".inf"):
        return float("-inf") if text.startswith("-") else float("inf")
    if lowered == ".nan":
        return float("nan")
    if text.startswith(("0o", "0x")):
        return float(_construct_int(loader, node))
    return float(text)


def _construct_bool(loader: _Loader, node: ScalarNode) -> bool:
    text = loader.construct_scalar(node)
    if not _BOOL_RE.match(text):
        raise _scalar_error(node, "true or false")
    return text.lower() == "true"


def _construct_other(loader: _Loader, node: Node):
    raise YamlError(f"(YAML) {_where(node.start_mark)}: found the tag "
                    f"{_clip(node.tag.replace(_TAG, '!!'), 40)}, expected plain values (null, "
                    "true/false, numbers, strings, lists, mappings)")


_Loader.yaml_implicit_resolvers = {}
for _tag, _regexp, _first in (
        ("null", _NULL_RE, ["~", "n", "N", ""]),
        ("bool", _BOOL_RE, list("tTfF")),
        ("int", _INT_RE, list("-+0123456789")),
        ("float", _FLOAT_RE, list("-+.0123456789")),
        ("merge", re.compile(r"^(?:<<)$"), ["<"])):
    _Loader.add_implicit_resolver(_TAG + _tag, _regexp, _first)
_Loader.yaml_constructors = {
    tag: fn for tag, fn in yaml.SafeLoader.yaml_constructors.items()
    if tag in (_TAG + "null", _TAG + "str", _TAG + "seq", _TAG + "map")}
_Loader.yaml_multi_constructors = {}
_Loader.add_constructor(None, _construct_other)
_Loader.add_constructor(_TAG + "int", _construct_int)
_Loader.add_constructor(_TAG + "float", _construct_float)
_Loader.add_constructor(_TAG + "bool", _construct_bool)


def _check_events(text: str) -> None:
    """Step 1 of the module docstring: depth, node count and scalar length."""
    loader = _Loader(text)
    depth = nodes = 0
    try:
        while loader.check_event():
            event = loader.get_event()
            if isinstance(event, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
                depth += 1
                if depth > MAX_DEPTH:
                    raise YamlError(f"(YAML) {_where(event.start_mark)}: found nesting "
                                    f"deeper than {MAX_DEPTH} levels, expected sections of "
                                    "keys")
            elif isinstance(event, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
                depth -= 1
            elif isinstance(event, yaml.ScalarEvent) and len(event.value) > MAX_SCALAR_CHARS:
                raise YamlError(f"(YAML) {_where(event.start_mark)}: found a value of "
                                f"{len(event.value):,} characters, expected at most "
                                f"{MAX_SCALAR_CHARS}")
            if isinstance(event, yaml.NodeEvent):
                nodes += 1
                if nodes > MAX_NODES:
                    raise YamlError(f"(YAML) {_where(event.start_mark)}: found more than "
                                    f"{MAX_NODES:,} values, expected a configuration")
    finally:
        loader.dispose()


def _children(node: Node) -> list[Node]:
    if isinstance(node, MappingNode):
        return [n for pair in node.value for n in pair]
    if isinstance(node, SequenceNode):
        return list(node.value)
    return []


def _check_expansion(root: Node) -> None:
    """Step 2: the node graph, aliases expanded, is finite and small (iterative DFS)."""
    size: dict[int, int] = {}
    on_path: set[int] = set()
    stack: list[tuple[Node, bool]] = [(root, False)]
    while stack:
        node, finished = stack.pop()
        key = id(node)
        if finished:
            on_path.discard(key)
            size[key] = 1 + sum(size[id(c)] for c in _children(node))
            if size[key] > MAX_EXPANDED_NODES:
                raise YamlError(f"(YAML) {_where(node.start_mark)}: found aliases that expand "
                                f"to more than {MAX_EXPANDED_NODES:,} values, expected a "
                                "configuration")
            continue
        if key in size:
            continue
        on_path.add(key)
        stack.append((node, True))
        for child in _children(node):
            if id(child) in on_path:
                raise YamlError(f"(YAML) {_where(child.start_mark)}: found an alias to a "
                                "value that contains it, expected a finite value")
            if id(child) not in size:
                stack.append((child, False))


def parse_yaml(text: str):
    """The data of one YAML document (None for an empty one); see the module docstring."""
    try:
        _check_events(text)
        loader = _Loader(text)
        try:
            root = loader.get_single_node()
            if root is None:
                return None
            _check_expansion(root)
            return loader.construct_document(root)
        finally:
            loader.dispose()
    except RecursionError:
        raise YamlError(f"(YAML) somewhere: found structure nested too deeply (through aliases "
                        f"or merges), expected at most {MAX_DEPTH} levels") from None
    except yaml.reader.ReaderError as exc:
        raise YamlError(f"(YAML syntax) at character {exc.position + 1}: found the control "
                        f"character U+{int(exc.character):04X}, expected printable text") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = re.sub(r"^(but )?found ", "", getattr(exc, "problem", None) or "")
        raise YamlError(f"(YAML syntax) {_where(mark)}: found {_clip(problem or 'bad text')}, "
                        "expected valid YAML") from None
