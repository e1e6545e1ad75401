"""Markdown tables for the reports, the reproductions and the generated reference pages, built from cells
so that the header, the separator and every row always have the same number of columns, whatever the
cells say: the one way the testbed writes a Markdown table."""

from __future__ import annotations

import re

#: a code span: a run of backticks, anything, the same run again (CommonMark)
_CODE_SPAN = re.compile(r"(`+)(?:.+?)\1", re.S)
#: a pipe not already escaped
_BARE_PIPE = re.compile(r"(?<!\\)\|")


def cell(value) -> str:
    """``value`` as the text of one table cell: a bare ``|`` outside code spans escaped (it would end the
    cell and shift every column after it), a line break made a space (it would end the row)."""
    text = " ".join(str(value).splitlines())
    out, at = [], 0
    for m in _CODE_SPAN.finditer(text):
        out += [_BARE_PIPE.sub(r"\\|", text[at:m.start()]), m.group(0)]
        at = m.end()
    out.append(_BARE_PIPE.sub(r"\\|", text[at:]))
    return "".join(out)


def table(header: list[str], rows: list[list]) -> list[str]:
    """The lines of a Markdown table; a row whose length differs from the header's is an error."""
    bad = [k for k, r in enumerate(rows) if len(r) != len(header)]
    if bad:
        raise ValueError(f"Markdown table rows {bad} have other than {len(header)} cells ({header})")
    line = lambda cells: "| " + " | ".join(cell(c) for c in cells) + " |"  # noqa: E731
    return [line(header), "|" + "---|" * len(header), *(line(r) for r in rows)]
