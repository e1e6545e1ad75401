"""Compiled per-epoch kernels of the monitors (numba).

The monitors are batched numpy around these loops. Each kernel walks the
epochs of a batch one at a time, in registers: the iterative solves stop when
*their* step is below the tolerance, and every other kernel decides each epoch
on its own, so an epoch's answer never depends on what else is in the batch
(the per-epoch reference implementations behave the same way). Each kernel is
checked against the numpy or LAPACK formula it replaces
(``tests/test_integrity_kernels.py``).

* :mod:`.small` – small dense linear algebra (LU, products);
* :mod:`.ranges` – the used-row gather and the range Gauss–Newton (GPS and vision rows; per epoch, and
  epochs side by side in vector lanes);
* :mod:`.geometry` – the weighted LS of an epoch: GᵀWG, its condition, J, A, (WS)ᵢᵢ, residuals,
  SSE, slopes and the reason code (epochs side by side in vector lanes);
* :mod:`.vision` – cosines and Σ_c, the cosine-rule solve (per epoch, and side by side) and its products, the vision
  prior and the integrated solve's vision block;
* :mod:`.calibration` – the GPS calibration of the vision ranges (per epoch, and side by side).

The kernels release the GIL, so callers may run chunks of a batch on threads.
They use numpy's floating-point error model: a division by zero gives inf/NaN
(and then an "unavailable" reason downstream), never an exception.
Compiled code is cached beside these files (numba's ``cache=True``); the first
call after an install compiles it (:func:`compile_all`, ~15–20 s).
"""

from __future__ import annotations

import numpy as np

from testbed.integrity.kernels.calibration import calibrate_epochs, calibrate_tiles
from testbed.integrity.kernels.geometry import wls_epochs, wls_one
from testbed.integrity.kernels.ranges import (
    gather_used_rows,
    range_gauss_newton,
    range_gauss_newton_tiles,
    scatter_used_rows,
)
from testbed.integrity.kernels.small import _lu_solve
from testbed.integrity.kernels.vision import (
    cosine_gauss_newton,
    cosine_gauss_newton_tiles,
    cosine_rule_products,
    cosine_rule_products_tiles,
    cosines_and_covariance,
    vision_prior,
    vision_rows,
)

__all__ = ["calibrate_epochs", "calibrate_tiles", "compile_all", "cosine_gauss_newton",
           "cosine_gauss_newton_tiles", "cosine_rule_products", "cosine_rule_products_tiles", "cosines_and_covariance", "gather_used_rows",
           "kernel_input", "range_gauss_newton", "range_gauss_newton_tiles", "scatter_used_rows",
           "vision_prior", "vision_rows", "wls_epochs", "wls_one", "_lu_solve"]


def kernel_input(a, shape: tuple, out_shape: tuple | None = None, dtype=np.float64) -> np.ndarray:
    """``a`` broadcast to ``shape`` (then reshaped to ``out_shape``), C-contiguous and read-only.

    numba compiles one specialisation per argument layout *and* writability, so every
    kernel input goes through here: one compiled version per kernel, whatever the caller's
    arrays are (fresh, broadcast views, read-only slices). Copies only when it must.
    """
    x = np.ascontiguousarray(np.broadcast_to(np.asarray(a, dtype), shape))
    if out_shape is not None:
        x = x.reshape(out_shape)
    v = x.view()
    v.flags.writeable = False
    return v


def compile_all() -> None:
    """Compile (or load from numba's cache) every kernel for the argument types the monitors use.

    Call it during set-up so the first epochs of a run are not charged with compilation
    (~15 s after an install, well under a second once cached). Inputs are read-only
    (:func:`kernel_input`), outputs fresh arrays, as in the monitors.
    """
    f, b, i = np.float64, np.bool_, np.int64

    def r(*shape, dt=f):  # an input
        return kernel_input(np.zeros(shape, dt), shape, dtype=dt)

    def w(*shape, dt=f):  # an output
        return np.zeros(shape, dt)

    gather_used_rows(r(1, 4, dt=b), r(1, 4), r(1, 4), r(1, 4, 3), r(3, 3), r(3), w(1, 3, dt=i), w(1, 3, dt=b), w(1, 3), w(1, 3),
                     w(1, 3, 3))
    scatter_used_rows(r(1, 3), r(1, 2, dt=i), r(1, 2, dt=b), w(1, 5))
    range_gauss_newton_tiles(r(1, 4, 3), r(1, 3), r(1, 4), r(1, 4), r(1, 4, dt=b), r(1, 3), r(1, 3), r(1, 0, 1),
                             r(1, 0), r(1, 0, 0), r(1, 0, dt=b), r(1, 4), r(1, dt=i), 1, 1e-3, w(1, 4), w(1, dt=b), w(1, dt=i),
                             w(1, 4), w(1, 4, 4))
    cosine_gauss_newton_tiles(r(1, 3), r(1, 3, 3), r(3), r(1, 3), r(1, 3, dt=b), r(1, 3, dt=b), 1, 1e-4, w(1, 3),
                              w(1, dt=i), w(1, dt=b), w(1, dt=b))
    wls_epochs(r(1, 5, 4), r(1, 5), r(1, 5), r(1, 2), r(1, 3, 3), r(1, 5, dt=b), 1e10, r(1, dt=i), w(1, 4, 4), w(1, 4, 5),
               w(1, 5), w(1), w(1, 5), w(1), w(1, 5), w(1, 5), w(1), w(1), w(1, dt=i), w(1, dt=i),
               w(1, dt=np.int8))
    for products in (cosine_rule_products, cosine_rule_products_tiles):
        products(r(1, 3), r(1, 3), r(3), r(1, 3, dt=b), r(1, 3, dt=b), r(1, 3, 3), r(1, 3, 3), r(1, 3), r(1, 3, 3),
                 w(1, 3, 3), w(1, 3), w(1, 3, 3), w(1, dt=b), w(1), w(1, 3, 3), w(1), w(1), w(1), w(1, dt=b))
    vision_rows(r(1, 3, 3), r(1, 3), r(1, 3, 3), r(1, 3, dt=b), r(1, 3, dt=b), r(1, dt=b), w(1, 3, 3), w(1, 3),
                w(1, 3, 3), w(1, 3, dt=b))
    vision_prior(r(1, 1, 4), r(1, 1, 3, 3), r(1, 1, dt=b), r(1), r(3, 3), r(1, 1, 3), 1.0, 1.0, w(1, 1, dt=i),
                 w(1, 1, 3), w(1, 1, 3, 3))
    cosines_and_covariance(r(1, 3, 2), r(1, 3, dt=b), r(1, 3), kernel_input(np.eye(3), (3, 3)), w(1, 3),
                           w(1, 3, 3))
    calibrate_tiles(r(1, 1, dt=i), r(1, 1, 3), r(1, 1, 3, 3), r(1, 1, 3), r(1, 1, 3, 3), r(1, 1, 3, 3),
                    r(1, 1, 3, 3), r(1, 1, 3, dt=b), r(1, 1, 3), r(1, 1, 3, 3), r(1, 1, 3), r(3, 3), r(3, 3),
                    w(1, 1, 3), w(1, 1, 3), w(1, 1, 3, 3), w(1, 1, 3, 3))
