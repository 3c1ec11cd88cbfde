"""HTML pages as a tree the tests can query (the standard library's parser; no browser):
``parse_html(page).find_all("details", class_="command")``."""

from __future__ import annotations


class Node:
    """An element of a parsed HTML page: tag, attributes, children and text."""

    def __init__(self, tag: str, attrs: dict[str, str | None]) -> None:
        self.tag, self.attrs = tag, attrs
        self.children: list[Node] = []
        self.parts: list[str] = []

    @property
    def text(self) -> str:
        return "".join(self.parts) + "".join(c.text for c in self.children)

    def find_all(self, tag: str, **attrs: str) -> list[Node]:
        out = []
        for c in self.children:
            if c.tag == tag and all(
                v in (c.attrs.get(k.rstrip("_")) or "").split() for k, v in attrs.items()
            ):
                out.append(c)
            out += c.find_all(tag, **attrs)
        return out


VOID = {"meta", "br", "input", "hr", "img", "link"}


def parse_html(page: str) -> Node:
    from html.parser import HTMLParser

    root = Node("#root", {})
    stack = [root]

    class P(HTMLParser):
        def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
            node = Node(tag, dict(attrs))
            stack[-1].children.append(node)
            if tag not in VOID:
                stack.append(node)

        def handle_endtag(self, tag: str) -> None:
            while len(stack) > 1:
                if stack.pop().tag == tag:
                    break

        def handle_data(self, data: str) -> None:
            stack[-1].parts.append(data)

    p = P()
    p.feed(page)
    p.close()
    return root
