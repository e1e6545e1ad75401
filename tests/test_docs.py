"""The documentation holds together: a short README with the two commands first, and no
page, README or module text naming a file the repository does not have."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOC_FILES = sorted([ROOT / "README.md", ROOT / "CHANGELOG.md", *(ROOT / "docs").rglob("*.md")])
SOURCE_FILES = sorted([*(ROOT / "testbed").rglob("*.py"), *(ROOT / "tests").rglob("*.py"),
                       *(ROOT / "benchmarks").rglob("*.py"), *(ROOT / "aircraft").rglob("*.toml"),
                       *(ROOT / "approaches").rglob("*.toml")])
#: a path into the repository, as prose or a code span writes it
REPO_PATH = re.compile(r"(?<![\w./-])((?:testbed|tests|benchmarks|docs|approaches|aircraft|\.ci)/[\w./-]*\w)")
#: a Markdown file named by its bare name (ARCHITECTURE.md, DPE.md, ...): it must exist somewhere here
BARE_MD = re.compile(r"(?<![\w./-])([A-Za-z][\w-]*\.md)\b")
MARKDOWN_LINK = re.compile(r"\]\(([^)\s]+)\)")
#: Markdown files the testbed writes (a campaign's report, a reproduction's claims), not repository files
OUTPUT_NAMES = {"report.md", "reproduce.md"}
#: folders made by a build or a run, not kept in the repository
BUILT = ("testbed/_shipped",)


def _exists(token: str) -> bool:
    token = token.rstrip(".")
    if any(ch in token for ch in "*<>{}") or token.startswith(BUILT):  # a pattern, a placeholder, a build product
        return True
    return (ROOT / token).exists() or (ROOT / token).with_suffix("").exists()


def _markdown_names() -> set[str]:
    return OUTPUT_NAMES | {p.name for p in ROOT.rglob("*.md") if ".venv" not in p.parts and ".git" not in p.parts}


def _without_fenced_output(text: str) -> str:
    """Drop ```text blocks (program output may name a user's files)."""
    return re.sub(r"```text\n.*?```", "", text, flags=re.S)


def test_the_readme_is_short_and_starts_with_the_two_commands():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 250, f"README.md has {len(lines)} lines; keep it to 250 and move detail to docs/"
    head = "\n".join(lines[:40])
    ci = (ROOT / ".ci" / "run").read_text()
    commands = re.findall(r"```bash\n(.*?)\n```", head, flags=re.S)
    assert len(commands) >= 2, "the README's first 40 lines must hold the set-up and test commands"
    setup, tests = commands[0], commands[1]
    assert "pip install" in setup and "testbed fly" in setup
    assert "pytest" in tests
    assert setup in ci and tests in ci, ".ci/run must run the README's two commands as written"


@pytest.mark.parametrize("path", DOC_FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_a_page_names_only_files_that_exist(path):
    text = _without_fenced_output(path.read_text())
    missing = [t for t in REPO_PATH.findall(text) if not _exists(t)]
    names = _markdown_names()
    missing += [t for t in BARE_MD.findall(text) if t not in names]
    for target in MARKDOWN_LINK.findall(text):
        if re.match(r"^[a-z]+:", target) or target.startswith("#"):
            continue
        file = target.split("#", 1)[0]
        if file and not (path.parent / file).exists():
            missing.append(target)
    assert missing == [], f"{path.relative_to(ROOT)} names files that are not in the repository"


def test_module_texts_name_only_files_that_exist():
    """Docstrings and comments of the package, the tests, the benchmarks and the shipped files: a cited design
    page (docs/...) or Markdown file must be in the repository, not in a private note."""
    names = _markdown_names()
    bad = []
    for path in SOURCE_FILES:
        if path == Path(__file__).resolve():
            continue
        text = path.read_text()
        for t in BARE_MD.findall(text):
            if t not in names:
                bad.append(f"{path.relative_to(ROOT)}: {t}")
        for t in REPO_PATH.findall(text):
            if t.startswith("docs/") and not _exists(t):
                bad.append(f"{path.relative_to(ROOT)}: {t}")
    assert bad == []


def test_module_docstrings_name_only_repository_paths_that_exist():
    bad = []
    for path in sorted((ROOT / "testbed").rglob("*.py")):
        doc = ast.get_docstring(ast.parse(path.read_text())) or ""
        bad += [f"{path.relative_to(ROOT)}: {t}" for t in REPO_PATH.findall(doc) if not _exists(t)]
    assert bad == []


def test_every_page_is_in_the_site_navigation():
    nav = (ROOT / "mkdocs.yml").read_text()
    pages = sorted(str(p.relative_to(ROOT / "docs")) for p in (ROOT / "docs").rglob("*.md"))
    assert [p for p in pages if f": {p}\n" not in nav] == []


def _report_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("bench_report", ROOT / "benchmarks" / "report.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_performance_page_is_made_from_the_benchmark_records_alone():
    report = _report_module()
    assert (ROOT / "docs" / "performance.md").read_text() == report.render(report.read_records()), (
        "docs/performance.md is generated: run `python benchmarks/report.py page`")


def test_a_damaged_benchmark_record_is_refused_naming_it(tmp_path, monkeypatch, capsys):
    report = _report_module()
    monkeypatch.setattr(report, "RESULTS", tmp_path)
    for text, message in (('{"name": "bench_flight"}', "bench_flight.json: a benchmark record needs the keys"),
                          ("{not json", "bench_flight.json: not a readable JSON record")):
        (tmp_path / "bench_flight.json").write_text(text)
        with pytest.raises(SystemExit) as exc:
            report.read_records()
        assert exc.value.code == 2 and message in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        report.main(["run", "no_such_benchmark"])
    assert exc.value.code == 2 and "no benchmark named 'no_such_benchmark'" in capsys.readouterr().err
