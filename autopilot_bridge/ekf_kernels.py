"""Covariance kernels of the navigation filter (``autopilot_bridge.ekf``), compiled with numba.

The 18-state covariance updates were a dozen small numpy calls each (products, fancy-indexed
diagonals, an identity, a Joseph form with N x N products for a one-row measurement): the calls,
not the arithmetic, were the cost. These kernels do the same algebra in one call each, in place,
allocating nothing (``_nrt=False``), single-threaded and deterministic. Pure: numpy and numba only.

* ``predict_covariance``: ``P <- F P F' + diag(q)`` with the error-state Jacobian ``F`` of
  ``NavFilter.predict`` (identity plus the dt, specific-force and rotation blocks, built here; the
  zero entries are skipped), then symmetrised. The wind states (15, 16) and the compass bias (17)
  are random walks: their rows of ``F`` are the identity's.
* ``update_direct``: a gated update with a direct measurement of up to three states (horizontal
  position, velocity) and its noise covariance, every state corrected, ``P <- P - K u'``.
* ``update_scalar``: a gated update with one measurement row ``h`` and noise variance ``r``. With
  ``joseph`` false every state is corrected, ``P <- P - K u'`` (``u = P h``, ``K = u / S``); with
  ``joseph`` true only the states where ``mask`` is 1 are (the Schmidt "consider" update of
  ``NavFilter._update``: the other gain rows are zero), in the Joseph form, which for one row is
  ``P - K u' - u K' + S K K'``. Symmetrised, variances floored at 1e-12.

Every kernel works on the first ``n`` states only (``n`` <= N): the filter passes 17 while the
compass-bias state (17) is off, so that the last row and column stay exactly zero and the
arithmetic, summation order included, is that of the 17-state filter.

The algebra is that of the numpy form it replaces; the rounding differs in the last bits (other
summation order), see docs/autopilot-control.md.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit

NO_NRT: dict[str, Any] = {"cache": True, "_nrt": False}
N = 18
VARIANCE_FLOOR = 1e-12


@njit(inline="always", **NO_NRT)
def _symmetrise_and_floor(P, N):  # pragma: no cover - compiled
    """P = (P + P') / 2 above the diagonal, variances at least ``VARIANCE_FLOOR`` (in place)."""
    for i in range(N):
        for j in range(i + 1, N):
            s = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = s
            P[j, i] = s
        if P[i, i] < VARIANCE_FLOOR:
            P[i, i] = VARIANCE_FLOOR


@njit(**NO_NRT)
def predict_covariance(P, tmp, dt, fx, fy, fz, rot, qd, n):  # pragma: no cover - compiled
    """In place: ``P <- F P F' + diag(qd)``, symmetrised; ``tmp`` is an N x N work array.

    ``(fx, fy, fz)``: specific force in the world frame (bias removed), ``rot``: body -> world at
    mid-tick, ``qd``: process noise variances for this dt (N)."""
    # tmp = F P, row by row: row i of F is e_i plus a few entries
    for i in range(n):
        for j in range(n):
            tmp[i, j] = P[i, j]
    for i in range(3):                       # d(dp) = dv dt
        for j in range(n):
            tmp[i, j] += dt * P[3 + i, j]
    # d(dv) = -[f]x dtheta dt - R db_a dt
    for j in range(n):
        a6 = P[6, j]
        a7 = P[7, j]
        a8 = P[8, j]
        tmp[3, j] += (fz * dt) * a7 + (-fy * dt) * a8
        tmp[4, j] += (-fz * dt) * a6 + (fx * dt) * a8
        tmp[5, j] += (fy * dt) * a6 + (-fx * dt) * a7
        for r in range(3):
            s = 0.0
            for c in range(3):
                s += (-dt * rot[r, c]) * P[12 + c, j]
            tmp[3 + r, j] += s
            s = 0.0
            for c in range(3):
                s += (-dt * rot[r, c]) * P[9 + c, j]
            tmp[6 + r, j] += s
    # P = tmp F' (column j of F' is row j of F)
    for i in range(n):
        for j in range(n):
            P[i, j] = tmp[i, j]
        for j in range(3):
            P[i, j] += dt * tmp[i, 3 + j]
        a6 = tmp[i, 6]
        a7 = tmp[i, 7]
        a8 = tmp[i, 8]
        P[i, 3] += (fz * dt) * a7 + (-fy * dt) * a8
        P[i, 4] += (-fz * dt) * a6 + (fx * dt) * a8
        P[i, 5] += (fy * dt) * a6 + (-fx * dt) * a7
        for r in range(3):
            s = 0.0
            for c in range(3):
                s += (-dt * rot[r, c]) * tmp[i, 12 + c]
            P[i, 3 + r] += s
            s = 0.0
            for c in range(3):
                s += (-dt * rot[r, c]) * tmp[i, 9 + c]
            P[i, 6 + r] += s
    for i in range(n):
        P[i, i] += qd[i]
    for i in range(n):
        for j in range(i + 1, n):
            s = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = s
            P[j, i] = s


@njit(**NO_NRT)
def update_scalar(P, h, r, innov, gate_sd, mask, joseph, apply, u, dx, n):  # pragma: no cover
    """Gated one-row update, in place (see the module docstring). Returns the test ratio
    (NIS / gate^2; inf for a singular S). ``u`` and ``dx`` (N) are outputs: ``P h`` before the
    update and the error-state correction (written only when applied). Applied when ``apply``
    and the ratio is finite and <= 1."""
    for i in range(n):
        s = 0.0
        for k in range(n):
            hk = h[k]
            if hk != 0.0:
                s += P[i, k] * hk
        u[i] = s
    S = r
    for k in range(n):
        if h[k] != 0.0:
            S += h[k] * u[k]
    if not (S != 0.0) or not np.isfinite(S):
        return np.inf
    ratio = innov * innov / S / (gate_sd * gate_sd)
    if not apply or not np.isfinite(ratio) or ratio > 1.0:
        return ratio
    inv_s = 1.0 / S
    # K = u / S on the corrected states (dx holds K until the end)
    for i in range(n):
        dx[i] = u[i] * inv_s * mask[i] if joseph else u[i] * inv_s
    if joseph:
        for i in range(n):
            ki = dx[i]
            ui = u[i]
            for j in range(n):
                P[i, j] += -ki * u[j] - ui * dx[j] + S * ki * dx[j]
    else:
        for i in range(n):
            ki = dx[i]
            for j in range(n):
                P[i, j] -= ki * u[j]
    _symmetrise_and_floor(P, n)
    for i in range(n):
        dx[i] *= innov
    return ratio



@njit(**NO_NRT)
def update_direct(P, idx, R, nu, gate_sd, apply, S, Sinv, U, K, dx, n):  # pragma: no cover - compiled
    """Gated update with a direct measurement of the states ``idx`` (m <= 3 of them: horizontal
    position 0, 1; velocity 3, 4, 5) with the m x m noise covariance ``R`` and innovation ``nu``,
    every state corrected (``P <- P - K u'``), in place. ``S``, ``Sinv`` (m x m), ``U``, ``K``
    (N x m) are work arrays. Returns the test ratio (inf for a singular S); ``dx`` (N) gets the
    correction when applied (``apply`` and the ratio finite and <= 1)."""
    m = idx.shape[0]
    for a in range(m):
        for b in range(m):
            S[a, b] = P[idx[a], idx[b]] + R[a, b]
            Sinv[a, b] = 1.0 if a == b else 0.0
    # Gauss-Jordan with partial pivoting: S -> I, Sinv -> S^-1
    for c in range(m):
        piv = c
        for a in range(c + 1, m):
            if abs(S[a, c]) > abs(S[piv, c]):
                piv = a
        if not (S[piv, c] != 0.0) or not np.isfinite(S[piv, c]):
            return np.inf
        if piv != c:
            for b in range(m):
                t = S[c, b]
                S[c, b] = S[piv, b]
                S[piv, b] = t
                t = Sinv[c, b]
                Sinv[c, b] = Sinv[piv, b]
                Sinv[piv, b] = t
        d = S[c, c]
        for b in range(m):
            S[c, b] /= d
            Sinv[c, b] /= d
        for a in range(m):
            if a != c:
                f = S[a, c]
                if f != 0.0:
                    for b in range(m):
                        S[a, b] -= f * S[c, b]
                        Sinv[a, b] -= f * Sinv[c, b]
    nis = 0.0
    for a in range(m):
        w = 0.0
        for b in range(m):
            w += Sinv[a, b] * nu[b]
        nis += nu[a] * w
    ratio = nis / (gate_sd * gate_sd)
    if not apply or not np.isfinite(ratio) or ratio > 1.0:
        return ratio
    for i in range(n):
        for a in range(m):
            U[i, a] = P[i, idx[a]]
    for i in range(n):
        x = 0.0
        for a in range(m):
            k = 0.0
            for b in range(m):
                k += U[i, b] * Sinv[b, a]
            K[i, a] = k
            x += k * nu[a]
        dx[i] = x
    for i in range(n):
        for j in range(n):
            s = 0.0
            for a in range(m):
                s += K[i, a] * U[j, a]
            P[i, j] -= s
    _symmetrise_and_floor(P, n)
    return ratio


_warm = False


def warm_up() -> None:
    """Load (or compile) every kernel once, on dummy arguments of the types the filter passes, so
    that the first control tick does not pay for it (~0.4 s of CPU with numba's on-disk cache).
    Once per process."""
    global _warm
    if _warm:
        return
    P = np.eye(N)
    v = np.zeros(N)
    predict_covariance(P, np.zeros((N, N)), 0.01, 0.0, 0.0, 9.8, np.eye(3), np.zeros(N), N)
    h = np.zeros(N)
    h[2] = 1.0
    update_scalar(P, h, 1.0, 0.0, 5.0, np.ones(N), True, True, np.zeros(N), v, N)
    for m in (2, 3):
        update_direct(P, np.arange(m, dtype=np.int64), np.eye(m), np.zeros(m), 5.0, True,
                      np.zeros((m, m)), np.zeros((m, m)), np.zeros((N, m)), np.zeros((N, m)), v, N)
    _warm = True
