"""Record benchmark runs and generate docs/performance.md from the records.

    python benchmarks/report.py run bench_flight [ARGS...]   # run benchmarks/bench_flight.py ARGS, keep a record
    python benchmarks/report.py run suite [PYTEST ARGS...]   # the test suite under /usr/bin/time -v
    python benchmarks/report.py page                         # write docs/performance.md from the records
    python benchmarks/report.py check                        # exit 1 if the page differs from the records

A record (``benchmarks/results/<name>.json``) keeps what the script printed, word for
word, beside the command, the commit (and whether the tree had uncommitted changes), the
date, the wall time and the machine: CPU model, cores, memory and the load average just
before and just after the run (the machine may be shared: the load says how busy it was).
The page is made from the records only, so no figure on it is typed by hand; a benchmark
script without a record is listed with its command as "not recorded".
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
PAGE = ROOT / "docs" / "performance.md"
RECORD_KEYS = {"name", "command", "stdout", "exit_code", "date_utc", "commit", "dirty", "wall_s", "machine"}
MACHINE_KEYS = {"cpu_model", "cores", "memory_gib", "load_before", "load_after", "python", "platform"}
#: helpers and tools in benchmarks/ that are not benchmarks of their own
NOT_BENCHMARKS = {"report", "timing", "readme_pictures", "pictures"}


def benchmark_names() -> list[str]:
    """Every benchmark script (``benchmarks/*.py`` less the helpers) and the test suite."""
    names = sorted(p.stem for p in (ROOT / "benchmarks").glob("*.py") if p.stem not in NOT_BENCHMARKS)
    return ["suite", *names]


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _memory_gib() -> float:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                return round(int(line.split()[1]) / 2**20, 1)
    except OSError:
        pass
    return float("nan")


def _git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=False).stdout.strip()


def _refuse(message: str):
    """Bad input: the message on stderr and exit code 2, before any work, never a traceback."""
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(2)


def command_for(name: str, args: list[str]) -> list[str]:
    if name == "suite":  # the README's test command (two processes)
        return ["/usr/bin/time", "-v", sys.executable, "-m", "pytest", "-q", "-n", "2", "-p", "no:cacheprovider", *args]
    script = ROOT / "benchmarks" / f"{name}.py"
    if name not in benchmark_names() or not script.is_file():
        _refuse(f"no benchmark named {name!r}; expected one of {', '.join(benchmark_names())}")
    return [sys.executable, str(script.relative_to(ROOT)), *args]


class _TreeMemory:
    """The peak of the summed proportional set size (PSS: shared pages split among their users) of a process and
    its descendants, sampled every 0.5 s from /proc on a thread (0 where /proc has no smaps_rollup)."""

    def __init__(self, pid: int) -> None:
        self.pid, self.peak, self._done = pid, 0, threading.Event()
        self._thread = threading.Thread(target=self._watch, daemon=True)
        self._thread.start()

    def _tree(self) -> list[int]:
        out, todo = [], [self.pid]
        while todo:
            p = todo.pop()
            out.append(p)
            for task in Path(f"/proc/{p}/task").glob("*/children"):
                try:
                    todo += [int(c) for c in task.read_text().split()]
                except OSError:
                    pass
        return out

    def _watch(self) -> None:
        while not self._done.wait(0.5):
            total = 0
            for p in self._tree():
                try:
                    for line in Path(f"/proc/{p}/smaps_rollup").read_text().splitlines():
                        if line.startswith("Pss:"):
                            total += int(line.split()[1]) * 1024
                except (OSError, ValueError):
                    pass
            self.peak = max(self.peak, total)

    def stop(self) -> int:
        self._done.set()
        self._thread.join()
        return self.peak


def run(name: str, args: list[str]) -> dict:
    """Run one benchmark, print its output as it comes, and store its record."""
    cmd = command_for(name, args)
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    memory = _TreeMemory(proc.pid)
    lines = []
    for line in proc.stdout:
        sys.stdout.write(line)
        lines.append(line)
    code = proc.wait()
    if name == "suite":  # time -v's peak is one process's; the workers run side by side
        lines.append(f"Peak summed PSS of the command's processes (sampled every 0.5 s): {memory.stop() / 2**30:.2f} GiB\n")
        sys.stdout.write(lines[-1])
    else:
        memory.stop()
    record = {
        "name": name,
        "command": " ".join(["python" if c == sys.executable else c for c in cmd]),
        "stdout": "".join(lines),
        "exit_code": code,
        "date_utc": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M"),
        "commit": _git("rev-parse", "--short=10", "HEAD"),
        "dirty": bool(_git("status", "--porcelain", "--untracked-files=no")),
        "wall_s": round(time.perf_counter() - t0, 1),
        "machine": {
            "cpu_model": _cpu_model(),
            "cores": os.cpu_count(),
            "memory_gib": _memory_gib(),
            "load_before": [round(x, 2) for x in load_before],
            "load_after": [round(x, 2) for x in os.getloadavg()],
            "python": platform.python_version(),
            "platform": platform.platform(terse=True),
        },
    }
    RESULTS.mkdir(exist_ok=True)
    tmp = RESULTS / f".{name}.json.part"
    tmp.write_text(json.dumps(record, indent=1, ensure_ascii=False) + "\n")
    tmp.replace(RESULTS / f"{name}.json")
    return record


def read_records() -> dict[str, dict]:
    """Every stored record, validated: a damaged or foreign file is an error naming it."""
    records = {}
    for path in sorted(RESULTS.glob("*.json")):
        where = f"benchmarks/results/{path.name}"
        try:
            rec = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            _refuse(f"{where}: not a readable JSON record ({exc})")
        missing = RECORD_KEYS - set(rec) if isinstance(rec, dict) else RECORD_KEYS
        if missing or not isinstance(rec.get("machine"), dict) or MACHINE_KEYS - set(rec["machine"]):
            _refuse(f"{where}: a benchmark record needs the keys "
                             f"{sorted(RECORD_KEYS)} and machine {sorted(MACHINE_KEYS)}")
        if rec["name"] != path.stem or rec["name"] not in benchmark_names():
            _refuse(f"{where}: name {rec['name']!r} is not this file's "
                             f"benchmark ({path.stem!r})")
        records[rec["name"]] = rec
    return records


def _docstring_line(name: str) -> str:
    if name == "suite":
        return "The test suite (the README's test command), its wall time and peak memory."
    import ast

    doc = ast.get_docstring(ast.parse((ROOT / "benchmarks" / f"{name}.py").read_text())) or ""
    first = " ".join(doc.strip().split("\n\n", 1)[0].split())
    return re.sub(r"^Benchmark( \([^)]*\))?: ", "", first).replace("|", "\\|")


def render(records: dict[str, dict]) -> str:
    out = [
        "# Performance and validation runs",
        "",
        "<!-- generated by `python benchmarks/report.py page` from benchmarks/results/*.json: do not edit -->",
        "",
        "Every figure on this page is what a benchmark script printed, kept word for word with the",
        "command, the commit, the date and the machine it ran on. The machine may have been shared:",
        "the load average before and after each run says how busy it was. Re-run one with",
        "`python benchmarks/report.py run NAME [ARGS...]` and regenerate this page with",
        "`python benchmarks/report.py page`.",
        "",
        "| benchmark | what it measures | recorded |",
        "| --- | --- | --- |",
    ]
    for name in benchmark_names():
        rec = records.get(name)
        when = f"[{rec['date_utc']}](#{name.replace('_', '-')})" if rec else "not recorded"
        out.append(f"| `{name}` | {_docstring_line(name)} | {when} |")
    for name in benchmark_names():
        rec = records.get(name)
        if rec is None:
            continue
        m = rec["machine"]
        out += [
            "",
            f"## {name.replace('_', '-')}",
            "",
            f"- command: `{rec['command']}` (exit code {rec['exit_code']}, {rec['wall_s']} s wall)",
            f"- commit: `{rec['commit']}`{' with uncommitted changes' if rec['dirty'] else ''}, "
            f"{rec['date_utc']} UTC",
            f"- machine: {m['cpu_model']}, {m['cores']} cores, {m['memory_gib']} GiB, Python {m['python']}; "
            f"load average (1/5/15 min) {' / '.join(map(str, m['load_before']))} before, "
            f"{' / '.join(map(str, m['load_after']))} after",
            "",
            "```text",
            rec["stdout"].rstrip("\n"),
            "```",
        ]
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run a benchmark and keep its record")
    r.add_argument("name", help="a benchmark script's name (bench_flight, ...) or 'suite'")
    r.add_argument("args", nargs=argparse.REMAINDER, help="arguments passed to the script")
    sub.add_parser("page", help="write docs/performance.md from the records")
    sub.add_parser("check", help="exit 1 if docs/performance.md is not the records' page")
    a = ap.parse_args(argv)
    if a.cmd == "run":
        rec = run(a.name, a.args)
        PAGE.write_text(render(read_records()))
        return 0 if rec["exit_code"] == 0 else 1
    page = render(read_records())
    if a.cmd == "page":
        PAGE.write_text(page)
        return 0
    if PAGE.read_text() != page:
        print("docs/performance.md differs from its records: run `python benchmarks/report.py page`")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
