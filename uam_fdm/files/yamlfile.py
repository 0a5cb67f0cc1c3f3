"""Strict, bounded reading of the YAML files users give us (scenarios, vehicles, maps).

One loader for every such file, so each gets the same checks before any value is used:

- a key repeated within one mapping is an error (PyYAML would keep the last one silently);
- the document may hold at most `MAX_YAML_VALUES` values with every alias expanded, and no alias
  may refer to itself: a few hundred bytes of nested aliases ("billion laughs") otherwise expand
  to billions of values the moment anything walks or prints them; nesting is at most
  `MAX_YAML_DEPTH` deep;
- the file may be at most `MAX_YAML_BYTES` long and must be UTF-8 text.

Every problem raises `ConfigError(file, key, reason)` with key ``<file>`` or ``<yaml>``.  What the
document holds is checked with the helpers of `uam_fdm.files.strict`.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from uam_fdm.errors import ConfigError

MAX_YAML_BYTES = 16 * 2**20  # a scenario or vehicle file is a few kB; a 20,000-building map is ~3 MB
MAX_YAML_VALUES = 250_000    # keys, values and list items after alias expansion (~19,000 explicit buildings)
MAX_YAML_DEPTH = 64          # nesting of lists and mappings; ours need 5, Python's repr fails near 1,000

# libyaml's parser when PyYAML was built with it (10x faster on large maps); same nodes, same checks
_BaseLoader = yaml.CSafeLoader if getattr(yaml, "__with_libyaml__", False) else yaml.SafeLoader


class StrictSafeLoader(_BaseLoader):  # type: ignore[misc, valid-type]
    """`yaml.SafeLoader` that rejects a key repeated within one mapping."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: set = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            try:
                duplicate = key in seen
                seen.add(key)
            except TypeError:  # an unhashable key: SafeLoader reports it below
                continue
            if duplicate:
                raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", key_node.start_mark)
        return super().construct_mapping(node, deep=deep)


MAX_INT_CHARS = 20
"""Characters of the longest integer a file may hold (2**63 has 19 digits): a longer one is a mistake, and
as a float it would overflow (OverflowError) or take seconds to convert."""


def _construct_int(loader: StrictSafeLoader, node: yaml.ScalarNode) -> int:
    """An integer scalar, refused (naming its line) when longer than `MAX_INT_CHARS`."""
    text = str(node.value).replace("_", "").lstrip("+-")
    if len(text) > MAX_INT_CHARS:
        raise yaml.constructor.ConstructorError(
            None, None, f"an integer of {len(text)} digits ({text[:12]}...): too large, at most {MAX_INT_CHARS}",
            node.start_mark)
    return yaml.constructor.SafeConstructor.construct_yaml_int(loader, node)


StrictSafeLoader.add_constructor("tag:yaml.org,2002:int", _construct_int)


def load_yaml_file(path: str | Path, source: str | None = None) -> Any:
    """Read and parse one YAML file strictly (see the module docstring).

    Args:
        path: the file.
        source: the name used in error messages (default: the path).

    Returns:
        The parsed document (None for an empty file).

    Raises:
        ConfigError: naming the file: not a readable file, too large, not UTF-8, not valid YAML,
            a duplicate key, or too many values after alias expansion.
    """
    path = Path(path)
    src = source or str(path)
    if path.is_dir():
        raise ConfigError(src, "<file>", "is a folder, not a YAML file")
    try:
        size = path.stat().st_size
        if size > MAX_YAML_BYTES:
            raise ConfigError(src, "<file>", f"{size:,} bytes: larger than the {MAX_YAML_BYTES:,}-byte limit "
                                             f"for a YAML file")
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(src, "<file>", f"cannot read: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(src, "<file>", f"not a text file (byte {exc.start} is not UTF-8): expected YAML") from None
    return parse_yaml(text, src)


def parse_yaml(text: str, source: str) -> Any:
    """Parse YAML text strictly (duplicate keys, bounded alias expansion); `source` names it in errors."""
    loader = StrictSafeLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        size = measure_document(node, MAX_YAML_VALUES)
        if size.recursive:
            raise ConfigError(source, "<yaml>", "an alias refers to itself (a recursive structure)")
        if size.values > MAX_YAML_VALUES:
            raise ConfigError(source, "<yaml>", f"more than {MAX_YAML_VALUES:,} values once aliases (*name) are "
                                                f"expanded: too large to check")
        if size.depth > MAX_YAML_DEPTH:
            raise ConfigError(source, "<yaml>", f"nested {size.depth} levels deep; at most {MAX_YAML_DEPTH}")
        return loader.construct_document(node)
    except yaml.YAMLError as exc:
        # PyYAML's message spans lines ("in <unicode string>, line 2, column 1"): one line, no noise
        lines = (ln.strip().replace('in "<unicode string>", ', "at ") for ln in str(exc).splitlines())
        raise ConfigError(source, "<yaml>", "not valid YAML: " + "; ".join(ln for ln in lines if ln)) from None
    except RecursionError:
        raise ConfigError(source, "<yaml>", "nested too deeply") from None
    finally:
        loader.dispose()


@dataclass(frozen=True)
class DocumentSize:
    """Size of a composed YAML document with every alias expanded.

    Attributes:
        values: nodes (keys, values, list items, containers), counted up to just past the limit asked for.
        depth: deepest nesting of containers (a scalar document has depth 1).
        recursive: an alias refers to a node that contains it (values and depth are then 0).
    """

    values: int
    depth: int
    recursive: bool = False


def measure_document(root: yaml.Node, max_values: int) -> DocumentSize:
    """Count the nodes under `root` as if every alias were expanded, without expanding any.

    Each distinct node is visited once (memoised, iterative), so this is linear in the document's
    size however far its aliases would expand; counting stops once the total passes `max_values`.
    """
    sizes: dict[int, tuple[int, int]] = {}  # id(node) -> (expanded values, depth)
    on_path: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        nid = id(node)
        if children_done:
            on_path.discard(nid)
            below = [sizes[id(c)] for c in _children(node)]
            values = 1 + sum(v for v, _ in below)
            depth = 1 + max((d for _, d in below), default=0)
            if values > max_values:
                return DocumentSize(values, depth)
            sizes[nid] = (values, depth)
            continue
        if nid in sizes:
            continue
        on_path.add(nid)
        stack.append((node, True))
        for child in _children(node):
            if id(child) in on_path:
                return DocumentSize(0, 0, recursive=True)
            if id(child) not in sizes:
                stack.append((child, False))
    return DocumentSize(*sizes[id(root)])


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    return []
