"""A small XML tree with the line of every element, for readers whose errors must name the line.

The standard library's ElementTree does not keep line numbers; :func:`read_xml` builds the same kind of tree
with expat (also standard library) and records the 1-based line of each start tag.  Writers use ElementTree.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
import xml.parsers.expat
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Iterator

import numpy as np
from numpy.typing import NDArray

from skyrig.errors import InputFormatError
from skyrig.io._text import atomic_write, parse_float

__all__ = ["XmlElement", "read_xml", "write_xml", "finite_float", "floats_of"]


@dataclass
class XmlElement:
    """An element: tag, attributes, text (stripped), children, and the line of its start tag."""

    tag: str
    attrib: dict[str, str]
    line: int
    text: str = ""
    children: list["XmlElement"] = field(default_factory=list)

    def find(self, tag: str) -> "XmlElement | None":
        """The first child with ``tag`` (a ``/``-separated path of tags), or None."""
        node: XmlElement | None = self
        for part in tag.split("/"):
            node = next((c for c in node.children if c.tag == part), None) if node is not None else None
        return node

    def findall(self, tag: str) -> list["XmlElement"]:
        """Children with ``tag`` (the last part of a ``/``-separated path)."""
        head, _, last = tag.rpartition("/")
        parent = self.find(head) if head else self
        return [] if parent is None else [c for c in parent.children if c.tag == last]

    def iter(self, tag: str) -> Iterator["XmlElement"]:
        """This element and all descendants with ``tag``, in document order."""
        if self.tag == tag:
            yield self
        for c in self.children:
            yield from c.iter(tag)


def read_xml(path: str | PathLike[str], data: bytes | None = None) -> XmlElement:
    """Parse ``path``: the root element; a malformed file is an :class:`InputFormatError` naming the line.
    ``data``: the XML's bytes when they come from elsewhere (a member of a zip archive), ``path`` then names it
    in messages."""
    p = Path(path)
    if data is None:
        try:
            data = p.read_bytes()
        except FileNotFoundError:
            raise InputFormatError("file not found", p) from None
    parser = xml.parsers.expat.ParserCreate()
    stack: list[XmlElement] = []
    root: list[XmlElement] = []
    texts: list[list[str]] = []

    def start(tag: str, attrib: dict[str, str]) -> None:
        e = XmlElement(tag, dict(attrib), parser.CurrentLineNumber)
        (stack[-1].children if stack else root).append(e)
        stack.append(e)
        texts.append([])

    def end(tag: str) -> None:
        e = stack.pop()
        e.text = "".join(texts.pop()).strip()

    def chars(s: str) -> None:
        if texts:
            texts[-1].append(s)

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = chars
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError as e:
        raise InputFormatError(f"not well-formed XML ({xml.parsers.expat.ErrorString(e.code)})", p, e.lineno) from None
    except (LookupError, ValueError) as e:  # e.g. an unknown encoding in the XML declaration
        raise InputFormatError(f"not readable XML ({e})", p, 1) from None
    if not root:
        raise InputFormatError("no XML element", p)
    return root[0]


def finite_float(text: str | None, path: Path, line: int | None, what: str) -> float:
    """``text`` as a finite float, else an :class:`InputFormatError` naming file, line and ``what``."""
    if text is None:
        raise InputFormatError("missing", path, line, what)
    return parse_float(text, path, line, what)  # type: ignore[arg-type]


def floats_of(e: XmlElement, n: int, path: Path, what: str) -> NDArray[np.float64]:
    """The ``n`` blank-separated numbers of an element's text (errors name its line and ``what``)."""
    parts = e.text.split()
    if len(parts) != n:
        raise InputFormatError(f"expected {n} numbers, got {len(parts)}", path, e.line, what)
    return np.array([finite_float(s, path, e.line, what) for s in parts])


def write_xml(path: str | PathLike[str], root: ET.Element) -> None:
    """Write an ElementTree (indented, UTF-8, with the XML declaration) atomically."""
    ET.indent(root)
    with atomic_write(path, "wb") as fh:
        fh.write(b'<?xml version="1.0" encoding="UTF-8"?>\n')
        fh.write(ET.tostring(root, encoding="utf-8"))
        fh.write(b"\n")
