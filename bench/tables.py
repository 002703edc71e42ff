"""Markdown tables, the one format every benchmark prints."""

from __future__ import annotations


def markdown_table(headers, rows) -> str:
    """A markdown table of ``headers`` and ``rows`` (each cell printed with ``str``)."""
    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)
