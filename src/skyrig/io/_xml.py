"""A small XML tree with the line of every element, for readers whose errors must name the line.

The standard library's ElementTree does not keep line numbers; :func:`read_xml` builds the same kind of tree
with expat (also standard library) and records the 1-based line of each start tag.  Writers use ElementTree.
"""

from __future__ import annotations

import xml.parsers.expat
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Iterator

from skyrig.errors import InputFormatError

__all__ = ["XmlElement", "read_xml"]


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


def read_xml(path: str | PathLike[str]) -> XmlElement:
    """Parse ``path``: the root element; a malformed file is an :class:`InputFormatError` naming the line."""
    p = Path(path)
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
    if not root:
        raise InputFormatError("no XML element", p)
    return root[0]
