"""Field-by-field comparison of records (MonitorOutput and its typed diagnostics, recursively)."""

from __future__ import annotations

import dataclasses
import re

import numpy as np


def assert_records_equal(a, b, path: str = "", rtol: float = 0.0, atol: float = 0.0) -> int:
    """Every field of two records equal (arrays: bit-identical, NaN == NaN, unless a tolerance
    is given for floats); nested records compared the same way. Returns the arrays compared."""
    assert type(a) is type(b), f"{path}: {type(a).__name__} vs {type(b).__name__}"
    n = 0
    for f in dataclasses.fields(a):
        va, vb, where = getattr(a, f.name), getattr(b, f.name), f"{path}{f.name}"
        if dataclasses.is_dataclass(va) and not isinstance(va, type):
            n += assert_records_equal(va, vb, where + ".", rtol, atol)
        elif isinstance(va, np.ndarray):
            assert va.shape == np.shape(vb), f"{where}: shape {va.shape} vs {np.shape(vb)}"
            if (rtol or atol) and np.issubdtype(va.dtype, np.floating):
                np.testing.assert_allclose(va, vb, rtol=rtol, atol=atol, err_msg=where)
            else:
                np.testing.assert_array_equal(va, vb, err_msg=where)
            n += 1
        else:
            assert va == vb or (va != va and vb != vb), f"{where}: {va!r} vs {vb!r}"
    return n


def _cells_in_row(line: str) -> int:
    """Cells of one table row as a Markdown renderer splits it: at pipes neither escaped (``\\|``) nor
    inside a code span."""
    bare = re.sub(r"(`+).+?\1", "", line.strip())  # code spans out
    return len(re.split(r"(?<!\\)\|", bare.strip("|"))) if bare.strip("|") else 1


def markdown_table_problems(text: str) -> list[str]:
    """Markdown tables whose header, separator and rows do not all have the same number of cells."""
    problems, block = [], []
    for line in [*text.splitlines(), ""]:
        if line.startswith("|"):
            block.append(line)
            continue
        if block:
            counts = [_cells_in_row(r) for r in block]
            if len(set(counts)) > 1 or len(block) < 2 or set(block[1]) - set("|-: "):
                problems.append(f"{block[0]!r}: cells per line {counts}")
            block = []
    return problems

