"""The configuration reference (docs/reference/configuration.md) is generated from the settings
models, lists every key of every model, and every field carries a description.

The models are walked here on their own (``model_fields`` recursion), not with the generator's
walk, so a key the generator skipped fails the test.
"""

from __future__ import annotations

import re
import types
import typing
from pathlib import Path

import pytest
from pydantic import BaseModel

from testbed.campaign.spec import CampaignSpec
from testbed.config import ApproachConfig
from testbed.docs_reference import COMMAND, numpy_prose, render
from testbed.flight.settings import AircraftSettings
from testbed.monitors import entry, monitor_names
from testbed.rinex.settings import MonitorFileConfig

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "reference" / "configuration.md"

#: page section (H2) -> root model of that kind of file
FILES = {"Approach file": ApproachConfig, "Aircraft file": AircraftSettings, "Campaign spec": CampaignSpec,
         "Monitor configuration file": MonitorFileConfig}
#: approach-file tables that ApproachConfig holds as free tables: each monitor's options, ``[monitor.<name>]``,
#: validated by the model the monitor declares
OPTION_TABLES = {f"monitor.{m}": (entry(m).options, set()) for m in monitor_names()}


def _models_in(tp) -> list[type[BaseModel]]:
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return [tp]
    out = []
    for a in typing.get_args(tp):
        out += _models_in(a)
    return out


def _is_free_table(tp) -> bool:
    return typing.get_origin(tp) is dict and typing.get_args(tp)[1] is typing.Any


def _reachable(root: type[BaseModel]) -> dict[type[BaseModel], set[str]]:
    """Every model reachable from ``root`` -> the keys its table takes."""
    seen: dict[type[BaseModel], set[str]] = {}

    def visit(model, skip=frozenset()):
        if model in seen:
            return
        seen[model] = set(model.model_fields) - set(skip)
        for name, f in model.model_fields.items():
            if name in skip:
                continue
            if model is ApproachConfig and name == "monitor":
                for sub, sub_skip in OPTION_TABLES.values():
                    visit(sub, sub_skip)
                continue
            for m in _models_in(f.annotation):
                visit(m)

    visit(root)
    return seen


def _table_paths(model: type[BaseModel], prefix: str = "", skip=frozenset()) -> list[str]:
    """The TOML table headers a file of ``model`` can have: ``[a.b]`` and ``[[a.b]]``."""
    out = []
    for name, f in model.model_fields.items():
        path = prefix + name
        if name in skip:
            continue
        if model is ApproachConfig and name == "monitor":
            for table, (sub, sub_skip) in OPTION_TABLES.items():
                out.append(f"[{table}]")
                out += _table_paths(sub, table + ".", sub_skip)
            continue
        tp = f.annotation
        arms = [a for a in typing.get_args(tp) if a is not type(None)] \
            if typing.get_origin(tp) in (typing.Union, types.UnionType) else [tp]
        if len(arms) == 1 and _models_in(arms[0]) == [arms[0]]:
            out.append(f"[{path}]")
            out += _table_paths(arms[0], path + ".")
        elif len(arms) == 1 and typing.get_origin(arms[0]) is list:
            for m in _models_in(typing.get_args(arms[0])[0]):
                if typing.get_origin(typing.get_args(arms[0])[0]) is list:
                    break  # an array of arrays: inline tables only, no header
                out.append(f"[[{path}]]")
                out += _table_paths(m, path + ".")
    return list(dict.fromkeys(out))


def _sections(text: str) -> dict[str, list[tuple[str, set[str]]]]:
    """H2 title -> [(H3 heading, keys in its table)]."""
    out: dict[str, list[tuple[str, set[str]]]] = {}
    h2 = None
    for line in text.splitlines():
        if line.startswith("## "):
            h2 = line[3:].strip()
            out[h2] = []
        elif line.startswith("### ") and h2 is not None:
            out[h2].append((line[4:].strip(), set()))
        elif line.startswith("| `") and h2 is not None and out[h2]:
            out[h2][-1][1].add(re.match(r"\| `([^`]+)`", line).group(1))
    return out


@pytest.fixture(scope="module")
def page() -> str:
    return render()


def test_the_committed_page_is_the_generated_one(page):
    committed = PAGE.read_text(encoding="utf-8") if PAGE.is_file() else ""
    assert committed == page, (f"{PAGE.relative_to(ROOT)} is out of date with the settings models: "
                               f"regenerate it with `{COMMAND}` (from the repository root)")


def test_every_key_of_every_model_is_in_the_page(page):
    secs = _sections(page)
    assert set(FILES) <= set(secs)
    missing = []
    everywhere = [keys for part in secs.values() for _, keys in part]
    for title, root in FILES.items():
        # a model inside an array of arrays (a campaign's landmark_sets) links to its table elsewhere
        for model, keys in _reachable(root).items():
            if keys not in everywhere:
                near = max(everywhere, key=lambda k: len(k & keys))
                missing.append(f"{title}: {model.__name__}: keys {sorted(keys - near)} not in any table")
        headings = " ".join(h for h, _ in secs[title])
        missing += [f"{title}: no section for {p}" for p in _table_paths(root) if f"`{p}`" not in headings]
    assert missing == []


def test_approach_free_tables_are_documented():
    free = [n for n, f in ApproachConfig.model_fields.items() if _is_free_table(f.annotation)]
    assert free == ["monitor"], "a free table of ApproachConfig needs its model in the page"
    assert sorted(OPTION_TABLES) == sorted(f"monitor.{m}" for m in monitor_names())


def test_every_field_has_a_description():
    models: dict[type[BaseModel], set[str]] = {}
    for root in [*FILES.values(), *(m for m, _ in OPTION_TABLES.values())]:
        for model in _reachable(root):
            models[model] = set(model.model_fields)
    bare = sorted(f"{m.__module__}.{m.__name__}.{n}" for m, names in models.items() for n in names
                  if not (m.model_fields[n].description or "").strip())
    assert bare == [], "fields without description= (the reference page prints it)"


def test_links_inside_the_page_have_anchors(page):
    anchors = set(re.findall(r'<a id="([^"]+)"></a>', page))
    links = set(re.findall(r"\]\(#([^)]+)\)", page))
    assert links and links <= anchors, sorted(links - anchors)


def test_numpy_prose_reads_the_project_docstrings():
    doc = ("Solve.\n>>> solve(1)\n2\n\nParameters\n----------\nx : the input (m).\n    More on x.\n"
           "y, z : two more.\n\nReturns\n-------\nthe fix, with :class:`~testbed.records.MonitorOutput` fields")
    assert numpy_prose(doc) == (
        "Solve.\n\n```pycon\n>>> solve(1)\n2\n```\n\nParameters\n----------\nx\n    the input (m).\n"
        "    More on x.\ny, z\n    two more.\n\nReturns\n-------\n:\n    the fix, with `MonitorOutput` fields")
