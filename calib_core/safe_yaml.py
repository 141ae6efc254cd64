"""YAML documents read within bounds: size, nesting depth and the nodes its aliases expand to.

PyYAML's safe loader builds an alias as a shared reference, so a few kilobytes of nested `&a [*a, *a]`
stand for billions of nodes that the first walk over the document (a `str()`, a copy, a check of every
field) expands; and its composer recurses once per nesting level, so a deep document ends in a
RecursionError. Every YAML the desk reads (profiles, desk and connection files, uploads) goes through
`load_yaml`: its events are counted first, in one pass that expands nothing, and a document beyond a
bound is refused with a sentence before it is built.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from .errors import InputError
from .files import read_text_file

MAX_YAML_BYTES = 1024 * 1024  # a profile, a desk file or a connection file is a few kilobytes
MAX_DEPTH = 64  # nesting levels (a profile nests five or six)
MAX_NODES = 250_000  # nodes with every alias expanded (a 1 MB document without aliases has fewer)

_Loader: type = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def load_yaml(text: str | bytes, source: str) -> Any:
    """The document of a YAML text; InputError naming `source` (and the line) when it is not valid YAML or
    passes a bound."""
    if len(text) > MAX_YAML_BYTES:
        raise InputError(
            f"a YAML file of at most {MAX_YAML_BYTES // 1024} kB is read ({len(text) // 1024} kB)", file=source
        )
    try:
        _check_bounds(text, source)
        return yaml.load(text, Loader=_Loader)  # a safe loader: no Python objects
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        raise InputError(f"not valid YAML ({getattr(exc, 'problem', None) or exc})", file=source, line=line) from None


def read_yaml(path: str | Path, what: str) -> Any:
    """load_yaml of a file (a regular file of at most MAX_YAML_BYTES); `what` names its kind in messages."""
    return load_yaml(read_text_file(path, MAX_YAML_BYTES, what), str(path))


def _check_bounds(text: str | bytes, source: str) -> None:
    """Walk the events once: the nesting depth, and the size of every node with its aliases expanded (an
    alias counts as the node its anchor names)."""
    anchors: dict[str, int] = {}
    open_nodes: list[list] = []  # per open collection: [anchor, nodes inside so far]
    total = 0
    for event in yaml.parse(text, Loader=_Loader):
        if isinstance(event, yaml.CollectionStartEvent):
            if len(open_nodes) >= MAX_DEPTH:
                raise _refusal(f"nests deeper than {MAX_DEPTH} levels", source, event)
            open_nodes.append([event.anchor, 1])
            continue
        if isinstance(event, yaml.CollectionEndEvent):
            anchor, size = open_nodes.pop()
        elif isinstance(event, yaml.ScalarEvent):
            anchor, size = event.anchor, 1
        elif isinstance(event, yaml.AliasEvent):
            anchor, size = None, anchors.get(event.anchor, 1)
        else:
            continue
        if anchor is not None:
            anchors[anchor] = size
        if open_nodes:
            open_nodes[-1][1] += size
        else:
            total += size
        if total + sum(n for _, n in open_nodes) > MAX_NODES:
            raise _refusal(f"expands to more than {MAX_NODES:,} nodes (aliases of aliases)", source, event)


def _refusal(what: str, source: str, event: yaml.Event) -> InputError:
    mark = event.start_mark
    return InputError(f"the YAML document {what}: not read", file=source, line=None if mark is None else mark.line + 1)
