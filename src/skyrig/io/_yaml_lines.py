"""YAML with line numbers: every mapping and sequence remembers its line (and each mapping the line of each key), so
that readers of skyrig's YAML files (rig files, scanner records, project files) name file, line and field."""

from __future__ import annotations

import os
from typing import Any

import yaml

from skyrig.errors import InputFormatError

__all__ = ["load_yaml_lines"]


class _Map(dict):  # type: ignore[type-arg]
    """A YAML mapping that remembers the line of itself and of each key (1-based)."""

    line: int = 0
    key_lines: dict[str, int]


class _Seq(list):  # type: ignore[type-arg]
    line: int = 0


def load_yaml_lines(text: str, path: str | os.PathLike[str]) -> Any:
    """The YAML document of ``text`` with line numbers on its mappings (:class:`_LineLoader`); any YAML error
    (a syntax error, a control character such as NUL) as :class:`InputFormatError` naming ``path`` and the line."""
    loader = None
    try:
        loader = _LineLoader(text)  # the reader refuses control characters here already
        loader._path = os.fspath(path)  # type: ignore[attr-defined]
        return loader.get_single_data()
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = None if mark is None else mark.line + 1
        raise InputFormatError(f"not valid YAML: {exc.problem or exc}", path, line) from None
    except yaml.reader.ReaderError as exc:
        line = text[: max(0, int(exc.position))].count("\n") + 1
        raise InputFormatError(f"not valid YAML: character {exc.character!r} is not allowed", path, line) from None
    except yaml.YAMLError as exc:
        raise InputFormatError(f"not valid YAML: {exc}", path) from None
    finally:
        if loader is not None:
            loader.dispose()


class _LineLoader(yaml.SafeLoader):
    pass


def _construct_mapping(loader: _LineLoader, node: yaml.MappingNode) -> _Map:
    loader.flatten_mapping(node)
    out = _Map()
    out.line = node.start_mark.line + 1
    out.key_lines = {}
    for k_node, v_node in node.value:
        key = loader.construct_object(k_node, deep=True)
        if not isinstance(key, str):
            raise InputFormatError(f"keys must be text, got {key!r}", getattr(loader, "_path", None),
                                   k_node.start_mark.line + 1)
        if key in out:
            raise InputFormatError(f"duplicate key {key!r}", getattr(loader, "_path", None), k_node.start_mark.line + 1)
        out[key] = loader.construct_object(v_node, deep=True)
        out.key_lines[key] = k_node.start_mark.line + 1
    return out


def _construct_sequence(loader: _LineLoader, node: yaml.SequenceNode) -> _Seq:
    out = _Seq(loader.construct_object(n, deep=True) for n in node.value)
    out.line = node.start_mark.line + 1
    return out


_LineLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)
_LineLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_SEQUENCE_TAG, _construct_sequence)


