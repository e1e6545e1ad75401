"""How the threads of numba's parallel kernels wait, set where a testbed process starts.

numba runs its parallel kernels (the DPE's manifold and posterior, the RINEX solve) on OpenMP
threads (GNU libgomp). An OpenMP thread with nothing to do spins for a while before it sleeps;
beside a busy neighbour (another program, or a campaign's other worker process on a 2-core
machine) the spinning threads take the cores the working ones need.
``python benchmarks/bench_dpe_neighbour.py`` measures the DPE approach alone and beside one
busy process with the threads as they are, told to sleep when idle, and cut to one thread.

:func:`sleep_idle_threads` sets ``OMP_WAIT_POLICY=passive`` (idle threads sleep at once) before
numba starts its thread pool. The command line and the campaign's worker processes call it when
they start; a library call never does. A value the user set wins.
"""

from __future__ import annotations

import os


def sleep_idle_threads() -> None:
    """Idle OpenMP threads sleep instead of spinning (unless ``OMP_WAIT_POLICY`` is already set)."""
    os.environ.setdefault("OMP_WAIT_POLICY", "passive")
