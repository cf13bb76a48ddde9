"""Parameter uncertainty of a Wiener PEM fit (:func:`rtlift.identify.pem.fit_wiener`): the
asymptotic covariance P = σ̂² (JᵀJ)⁻¹ of the physical parameters (a, c, p) with J the Jacobian of
ε (Ljung eq. 9.17), σ̂² = Σε²/(N − d), and by the delta method the poles' and the DC gain's; poles
the data cannot separate are reported as a group.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from rtlift.identify.problem import _Problem


def _output_jacobian(prob: _Problem, a, c, p, beta) -> np.ndarray:
    """∂ẑ/∂(a, c[, p, β]) analytically (Ljung §10.3, the OE gradient):
    ∂y/∂aᵢ = −q⁻ⁱ y / A(q),  ∂y/∂cⱼ = q^{−j+1} u / A(q),  ∂ẑ/∂θ = (∂ẑ/∂y)·∂y/∂θ with
    ∂ẑ/∂y = N(u) (input gain), f′(y) (table) or Σ d p_d y^{d−1} (polynomial)."""
    den = np.concatenate([[1.0], a])
    n = a.size
    x1 = signal.lfilter([1.0], den, prob.u)
    y = signal.lfilter(c, den, prob.u)
    w = signal.lfilter([1.0], den, y)
    if prob.form == "input_gain":
        dz = prob.gain
    elif prob.form == "output_map":
        xt, ft = prob.table
        slope = np.diff(ft) / np.diff(xt)
        dz = slope[np.clip(np.searchsorted(xt, y, side="right") - 1, 0, slope.size - 1)]
    else:
        dz = np.polyval((np.arange(1, p.size) * p[1:])[::-1], y)
    cols = []
    for i in range(1, n + 1):
        cols.append(-dz * np.concatenate([np.zeros(i), w[:-i]]))
    for j in range(n):
        cols.append(dz * (np.concatenate([np.zeros(j), x1[:-j]]) if j else x1))
    if p is not None:
        cols += [y**d for d in range(p.size)]
    if beta is not None:
        cols += list(prob.extra.T)
    return np.column_stack(cols)[prob.mask]


def _covariance(J: np.ndarray, sigma2: float, Q: np.ndarray | None = None) -> np.ndarray:
    """P = σ̂² (JᵀJ)⁺ (on the subspace spanned by Q's columns when given: Q (QᵀJᵀJQ)⁺ Qᵀ),
    from the SVD of J with its columns scaled to unit norm rather than from JᵀJ: the
    parameters' scales differ by orders of magnitude, and the pseudo-inverse of the unscaled
    normal matrix (condition number squared) kept or dropped near-null directions by rounding,
    which changed with the floating-point order of a threaded BLAS from run to run. Directions
    whose scaled singular value is below 1e-8 of the largest are not estimable and left out."""
    M = J if Q is None else J @ Q
    d = np.linalg.norm(M, axis=0)
    d = np.where(d > 0, d, 1.0)
    _, sv, vt = np.linalg.svd(M / d, full_matrices=False)
    keep = sv > 1e-8 * sv[0] if sv.size else sv.astype(bool)
    W = vt[keep].T / sv[keep]                      # scaled parameters: (M/d)⁺ᵀ-like factor
    P = sigma2 * (W / d[:, None]) @ (W / d[:, None]).T
    return P if Q is None else Q @ P @ Q.T


def pole_sensitivity(a: np.ndarray, poles: np.ndarray) -> np.ndarray:
    """∂pᵢ/∂a_k for the roots of A(z) = zⁿ + a₁zⁿ⁻¹ + … + aₙ (implicit differentiation of
    A(pᵢ) = 0): ∂pᵢ/∂a_k = −pᵢⁿ⁻ᵏ / A′(pᵢ), A′(pᵢ) = Πⱼ≠ᵢ (pᵢ − pⱼ). Analytic, so no finite
    step (a step of 1e-7·|a| across a near-double pole could split the pair into a complex
    one and reorder the roots); infinite where two poles coincide."""
    n = a.size
    out = np.empty((n, n), dtype=complex)
    for i, p in enumerate(poles):
        dA = np.prod([p - q for j, q in enumerate(poles) if j != i]) if n > 1 else 1.0
        out[i] = -(p ** np.arange(n - 1, -1, -1)) / dA if dA != 0 else np.inf
    return out


def _pole_uncertainty(a: np.ndarray, poles: np.ndarray, P_a: np.ndarray) -> tuple[list, list[dict]]:
    """Each pole's standard deviation by the delta method, where it is defined; and the
    groups of poles it is not defined for, with the uncertainty of what is.

    The delta method holds for a pole only while its predicted spread is small against its
    distance to every other pole. Taking the pairs nearest first, two groups of poles (at
    first single poles) closer than 3 (σ₁ + σ₂) are merged, σ of a group being that of its
    mean, a smooth function of the coefficients (its gradient −Σᵢ pᵢⁿ⁻ᵏ/A′(pᵢ) over the group
    stays finite as the poles merge, while each pole's own ∝ 1/|pᵢ − pⱼ| does not). A
    near-double pole the data cannot split is so reported as a group: each member's std
    ``None``, the group's mean with its std."""
    n = a.size
    G = pole_sensitivity(a, poles)

    def sigma(idx: list[int]) -> float:
        g = np.sum(G[idx], axis=0) / len(idx)
        if not np.all(np.isfinite(g)):
            return np.inf
        return float(np.sqrt(abs(g.real @ P_a @ g.real) + abs(g.imag @ P_a @ g.imag)))

    groups = [[i] for i in range(n)]
    where = list(range(n))                          # pole -> its group's index in ``groups``
    pairs = sorted((abs(poles[p] - poles[q]), p, q) for p in range(n) for q in range(p + 1, n))
    for distance, i, j in pairs:
        gi, gj = where[i], where[j]
        if gi == gj or distance >= 3.0 * (sigma(groups[gi]) + sigma(groups[gj])):
            continue
        groups[gi] = sorted(groups[gi] + groups[gj])
        for k in groups[gj]:
            where[k] = gi
        groups[gj] = []
    pole_std: list = [None] * n
    clusters = []
    for idx in (g for g in groups if g):
        sd = sigma(idx)
        if len(idx) == 1:
            pole_std[idx[0]] = sd if np.isfinite(sd) else None
            continue
        mean = complex(np.mean(poles[idx]))
        clusters.append({"poles": idx, "mean": [mean.real, mean.imag], "mean_std": sd if np.isfinite(sd) else None,
                         "spread": float(max(abs(poles[i] - poles[j]) for i in idx for j in idx)),
                         "note": "closer than their uncertainty: not separable from this record, so each "
                                 "pole's std is not defined; the mean of the group is"})
    return pole_std, clusters


def _uncertainty(prob: _Problem, a, c, p, beta, sigma2: float, fs_hz: float) -> dict:
    """Standard deviations from P = σ̂² (JᵀJ)⁻¹ over the physical parameters (a, c[, p, β])
    and by the delta method for the poles and the DC gain (Ljung eq. 9.17, 9.51); poles the
    data cannot separate are reported as a group (:func:`_pole_uncertainty`)."""
    n = a.size
    npoly = 0 if p is None else p.size
    parts = [a, c] + ([p] if p is not None else []) + ([beta] if beta is not None else [])
    x = np.concatenate(parts)

    J = _output_jacobian(prob, a, c, p, beta)
    gdc = np.zeros(x.size)
    gdc[:n] = -np.sum(c) / (1 + np.sum(a)) ** 2
    gdc[n:2 * n] = 1.0 / (1 + np.sum(a))
    if prob.form == "output_poly":
        # G(1) = 1 is a normalisation, not an estimate: leave the scale direction out
        Q = np.linalg.svd(gdc[None, :])[2][1:].T          # basis of {δ: gᵀδ = 0}
        P = _covariance(J, sigma2, Q)
    else:
        P = _covariance(J, sigma2)
    std = np.sqrt(np.maximum(np.diag(P), 0.0))
    base = np.sort_complex(np.roots(np.concatenate([[1.0], a])))
    pole_std, clusters = _pole_uncertainty(a, base, P[:n, :n])
    dc_std = float(np.sqrt(max(gdc @ P @ gdc, 0.0)))
    tau = -1.0 / (fs_hz * np.log(np.abs(base)))
    out = {
        "a_std": std[:n].tolist(),
        "c_std": std[n:2 * n].tolist(),
        "poles": [[float(z.real), float(z.imag)] for z in base],
        "poles_std": pole_std,
        "time_constants_s": tau.tolist(),
        "dc_gain_std": dc_std,
        "sigma": float(np.sqrt(sigma2)),
        "note": "asymptotic (white-residual) covariance; coloured residuals make it optimistic",
    }
    if clusters:
        out["pole_clusters"] = clusters
    if p is not None:
        out["poly_std"] = std[2 * n:2 * n + npoly].tolist()
    if beta is not None:
        out["extra_coef_std"] = std[2 * n + npoly:].tolist()
    return out
