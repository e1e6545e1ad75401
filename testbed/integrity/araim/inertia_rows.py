"""An inertial position prediction as three ARAIM rows with a fault event of its own (docs/design/araim.md §11).

A filter's (or an inertial coast's) position predicted for this epoch before its update, p⁻ with covariance
P⁻, is a direct measurement of the position. Whitened by the Cholesky factor of P⁻ (P⁻ = L Lᵀ) its three
rows L⁻¹ p⁻ = L⁻¹ p + w have unit, independent errors, so they enter the ARAIM rows like any other; the
three are one fault event (prior ``AraimSettings.inertia``) and are removed together, so the whitening never
mixes a kept row with a removed one.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike

from testbed.integrity.araim.core import AraimRows
from testbed.integrity.araim.fault_modes import AID_INERTIA


def with_inertial_prediction(rows: AraimRows, p_pred: ArrayLike, P_pred: ArrayLike,
                             p_lin: ArrayLike | None = None) -> AraimRows:
    """``rows`` with the three whitened rows of a position prediction appended to their aid rows.

    Parameters
    ----------
    rows : the epochs' rows, batch (...).
    p_pred : (..., 3) m predicted antenna position (ENU, the rows' frame); NaN: no prediction that epoch.
    P_pred : (..., 3, 3) m² its covariance (symmetric positive definite where ``p_pred`` is finite; else the
        epoch's rows are NaN and the epoch unavailable, as for any NaN row).
    p_lin : (..., 3) m the position the rows' residuals were taken at (required when ``rows.residual`` is
        given: the prediction's residual is p⁻ − p_lin).
    """
    batch = np.shape(rows.used)[:-1]
    p_pred = np.broadcast_to(np.asarray(p_pred, float), batch + (3,))
    P_pred = np.broadcast_to(np.asarray(P_pred, float), batch + (3, 3))
    if rows.residual is not None and p_lin is None:
        raise ValueError("with_inertial_prediction: rows carry residuals, so p_lin (where they were taken) is needed")
    given = np.isfinite(p_pred).all(-1)
    L = _cholesky_or_nan(P_pred, given)
    Linv = np.linalg.inv(L)  # (..., 3, 3) whitening; NaN where P⁻ is not positive definite
    K = 0 if rows.aid_g is None else np.shape(rows.aid_g)[-1] - 3
    g_new = np.concatenate([Linv, np.zeros(batch + (3, K))], -1)
    c_new = np.ones(batch + (3,))
    res_new = None
    if rows.residual is not None:
        innovation = np.where(given[..., None], p_pred - np.asarray(p_lin, float), 0.0)
        res_new = np.einsum("...ij,...j->...i", Linv, innovation)
    label_new = np.array([(AID_INERTIA, q) for q in range(3)], int)
    if rows.aid_g is None:
        return replace(rows, aid_g=g_new, aid_state=np.zeros((3, 0), bool), aid_label=label_new,
                       aid_used=np.broadcast_to(given[..., None], batch + (3,)).copy(), aid_c=c_new,
                       aid_residual=res_new)
    return replace(rows, aid_g=np.concatenate([np.asarray(rows.aid_g, float), g_new], -2),
                   aid_state=np.concatenate([np.asarray(rows.aid_state, bool), np.zeros((3, K), bool)], 0),
                   aid_label=np.concatenate([np.asarray(rows.aid_label, int), label_new], 0),
                   aid_used=np.concatenate([np.asarray(rows.aid_used, bool),
                                            np.broadcast_to(given[..., None], batch + (3,))], -1),
                   aid_c=np.concatenate([np.asarray(rows.aid_c, float), c_new], -1),
                   aid_residual=None if res_new is None else np.concatenate([np.asarray(rows.aid_residual, float),
                                                                             res_new], -1))


def _cholesky_or_nan(P, given):
    """Per epoch: the Cholesky factor, NaN where the covariance is not symmetric positive definite (one batched
    factorisation; the epochs one at a time only when one of them fails)."""
    flat = np.where(given[..., None, None], P, np.eye(3)).reshape(-1, 3, 3)
    symmetric = np.isclose(flat, np.swapaxes(flat, -1, -2), rtol=1e-9, atol=0.0).all((-1, -2))
    if symmetric.all():
        try:
            return np.linalg.cholesky(flat).reshape(P.shape)
        except np.linalg.LinAlgError:
            pass
    out = np.full_like(flat, np.nan)
    for i, m in enumerate(flat):
        if np.allclose(m, m.T, rtol=1e-9, atol=0.0) and np.all(np.isfinite(m)):
            try:
                out[i] = np.linalg.cholesky(m)
            except np.linalg.LinAlgError:
                pass
    return out.reshape(P.shape)
