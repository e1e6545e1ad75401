"""Every shell and Python block of the README and the documentation runs as written.

A page's ``bash`` and ``python`` blocks run in order in one fresh empty folder (a later
block may use what an earlier one wrote), with this interpreter's ``bin`` folder first on
PATH so that ``python`` and ``testbed`` are the ones under test. A block that must not run
here (it installs, opens a viewer, serves, or takes many minutes) carries the HTML comment
``<!-- not run: REASON -->`` on the line before it; the reason is required.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md")])
RUNNABLE = {"bash", "python"}
FENCE = re.compile(r"^```([\w+-]*)[^\n]*\n(.*?)^```\s*$", re.S | re.M)
NOT_RUN = re.compile(r"<!--\s*not run:\s*(.*?)\s*-->\s*$")


@dataclass(frozen=True)
class Block:
    page: Path
    line: int
    lang: str
    code: str
    not_run: str | None  # the reason, when marked


def blocks(page: Path) -> list[Block]:
    text = page.read_text()
    out = []
    for m in FENCE.finditer(text):
        before = text[: m.start()].rstrip("\n").rsplit("\n", 1)[-1]
        mark = NOT_RUN.search(before)
        out.append(Block(page, text.count("\n", 0, m.start()) + 1, m.group(1), m.group(2),
                         mark.group(1) if mark else None))
    return out


def _id(page: Path) -> str:
    return str(page.relative_to(ROOT))


def test_every_not_run_mark_gives_a_reason_and_sits_on_a_runnable_block():
    bad = []
    for page in PAGES:
        text = page.read_text()
        marks = len(re.findall(r"^<!--\s*not run", text, flags=re.M))
        marked = [b for b in blocks(page) if b.not_run is not None]
        if marks != len(marked):
            bad.append(f"{_id(page)}: a 'not run' mark not on the line just before a block")
        bad += [f"{_id(page)}:{b.line}: no reason" for b in marked if not b.not_run]
        bad += [f"{_id(page)}:{b.line}: marks a {b.lang or 'plain'} block, which never runs"
                for b in marked if b.lang not in RUNNABLE]
    assert bad == []


RUN_PAGES = [p for p in PAGES if any(b.lang in RUNNABLE and b.not_run is None for b in blocks(p))]
#: a tutorial flies, runs a campaign or a reproduction (tens of seconds each): the slow set; the other
#: pages' examples are one-line calculations and stay in the default set
PAGE_PARAMS = [pytest.param(p, marks=pytest.mark.slow) if p.parent.name == "tutorials" else p for p in RUN_PAGES]


@pytest.mark.parametrize("page", PAGE_PARAMS, ids=_id)
def test_a_pages_examples_run(page, tmp_path):
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["MPLBACKEND"] = "Agg"
    for b in blocks(page):
        if b.lang not in RUNNABLE or b.not_run is not None:
            continue
        cmd = ["bash", "-euo", "pipefail", "-c", b.code] if b.lang == "bash" else [sys.executable, "-c", b.code]
        proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
        assert proc.returncode == 0, (f"{_id(page)}:{b.line} ({b.lang}) exited {proc.returncode}\n"
                                      f"--- stdout\n{proc.stdout[-3000:]}\n--- stderr\n{proc.stderr[-3000:]}")
