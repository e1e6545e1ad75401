"""numba's on-disk cache follows an edit of a helper in another file (testbed.kernel_cache).

Each run is a fresh interpreter on a scratch package: ``user_guarded`` and ``user_plain``
define the same cached kernel over a cached helper of ``helper.py``; only the first calls
the stamp of :func:`testbed.kernel_cache.keep_in_step`. After the helper is edited, numba alone keeps
running the old helper (the hazard, checked so that the guard's test means something); the
guarded kernel runs the new one, and an unchanged tree is served from the cache.
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

from testbed.kernel_cache import KERNEL_SOURCES, PACKAGE

HELPER = """
from numba import njit


@njit(cache=True)
def h(x):
    return x + {add}
"""

USER = """
import sys
from pathlib import Path

from numba import njit

from pkgx.helper import h
from testbed.kernel_cache import keep_in_step


@njit(cache=True)
def f(x):
    return 2 * h(x)


HERE = Path(__file__).parent
STAMPED = keep_in_step(sys.modules[__name__], [HERE / "helper.py", HERE / "user_guarded.py"]) if {guard} else None
"""

RUN = """
import json
import pkgx.user_guarded as g, pkgx.user_plain as p
print(json.dumps({"guarded": g.f(1), "guarded_float": g.f(1.5), "plain": p.f(1), "stamped": g.STAMPED,
                  "hits": sum(g.f.stats.cache_hits.values())}))
"""


def _scratch_package(root: Path) -> Path:
    """``root/pkgx``: the helper (x + 1) and the two users of it."""
    pkg = root / "pkgx"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "helper.py").write_text(HELPER.format(add=1))
    (pkg / "user_guarded.py").write_text(USER.format(guard=True))
    (pkg / "user_plain.py").write_text(USER.format(guard=False))
    return pkg


def _env(root: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env["PYTHONPATH"] = str(root)
    return env


def _run(root: Path) -> dict:
    out = subprocess.run([sys.executable, "-c", RUN], env=_env(root), cwd=root, capture_output=True, text=True,
                         timeout=300, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_an_edited_helper_reaches_a_cached_kernel_in_another_file(tmp_path):
    pkg = _scratch_package(tmp_path)

    first = _run(tmp_path)
    assert (first["guarded"], first["plain"]) == (4, 4)

    (pkg / "helper.py").write_text(HELPER.format(add=2))
    edited = _run(tmp_path)
    assert edited["plain"] == 4, "numba now follows helpers itself: testbed.kernel_cache may go"
    assert edited["guarded"] == 6
    assert edited["stamped"] == 1

    again = _run(tmp_path)
    assert again["guarded"] == 6
    assert again["hits"] >= 1  # served from the cache: the guard does not defeat it


def test_every_module_with_cached_kernels_keeps_in_step():
    def caches(path: Path) -> bool:  # a call with cache=True (numba's njit) anywhere in the module
        return any(isinstance(n, ast.keyword) and n.arg == "cache" and getattr(n.value, "value", None) is True
                   for n in ast.walk(ast.parse(path.read_text())))

    with_cache = sorted(p.relative_to(PACKAGE).as_posix() for p in PACKAGE.rglob("*.py") if caches(p))
    assert with_cache == sorted(KERNEL_SOURCES)
    for rel in with_cache:
        last = ast.parse((PACKAGE / rel).read_text()).body[-1]
        assert ast.unparse(last) == "keep_in_step(sys.modules[__name__])", rel


def test_a_process_started_before_the_edit_cannot_pass_its_old_code_on(tmp_path):
    """A long-lived process (a Dask worker, a notebook) imported the old helper; after the edit it compiles
    a new signature and writes the index with its own, old stamp. The next new process does not trust it."""
    pkg = _scratch_package(tmp_path)
    old = subprocess.Popen([sys.executable, "-c", "import sys, pkgx.user_guarded as g; print(g.f(1), flush=True); "
                                                  "sys.stdin.readline(); print(g.f(1.5), flush=True)"],
                           env=_env(tmp_path), cwd=tmp_path, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert old.stdout.readline().strip() == "4"
        (pkg / "helper.py").write_text(HELPER.format(add=2))
        assert _run(tmp_path)["guarded"] == 6  # a new process sees the edit (and compiles only the int signature)
        out, _ = old.communicate("go\n", timeout=300)
        assert out.strip() == "5.0"  # the old process, a new signature, old code: 2 * (1.5 + 1)
    finally:
        old.kill()
    assert _run(tmp_path)["guarded_float"] == 7.0  # its entry for that signature (old stamp) is not trusted
