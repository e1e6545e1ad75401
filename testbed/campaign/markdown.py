"""Markdown tables for the campaign and reproduction reports, built from cells so that the header,
the separator and every row always have the same number of columns."""

from __future__ import annotations


def table(header: list[str], rows: list[list]) -> list[str]:
    """The lines of a Markdown table; a row whose length differs from the header's is an error."""
    bad = [k for k, r in enumerate(rows) if len(r) != len(header)]
    if bad:
        raise ValueError(f"Markdown table rows {bad} have other than {len(header)} cells ({header})")
    line = lambda cells: "| " + " | ".join(str(c) for c in cells) + " |"  # noqa: E731
    return [line(header), "|" + "---|" * len(header), *(line(r) for r in rows)]
