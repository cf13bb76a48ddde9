"""The output-error problem of a Wiener PEM fit (:func:`rtlift.identify.pem.fit_wiener`): θ → the
output error ε(θ) on the samples in the cost, with the parameters that enter linearly (c for
``input_gain``, p for ``output_poly``, β of extra regressors) eliminated by linear least squares for
every θ (variable projection, Golub & Pereyra 1973); and the static part ẑ = static(u, y) of each
form.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from rtlift.identify.poles import denominator_from_theta


def _static(form, u, y, gain, table, poly):
    if form == "input_gain":
        return gain * y
    if form == "output_map":
        return _interp_extrap(y, table[0], table[1])
    return np.polyval(poly[::-1], y)


def _interp_extrap(v: np.ndarray, x: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Linear interpolation continuing the end segments (as OutputNonlinearity does)."""
    out = np.interp(v, x, f)
    lo, hi = v < x[0], v > x[-1]
    out[lo] = f[0] + (v[lo] - x[0]) * (f[1] - f[0]) / (x[1] - x[0])
    out[hi] = f[-1] + (v[hi] - x[-1]) * (f[-1] - f[-2]) / (x[-1] - x[-2])
    return out


@dataclass
class _Problem:
    u: np.ndarray
    z: np.ndarray
    order: int
    form: str
    gain: np.ndarray | None
    table: tuple[np.ndarray, np.ndarray] | None
    degree: int
    mask: slice | np.ndarray          # samples in the cost (skip:, or explicit indices)
    r_max: float
    extra: np.ndarray | None = None   # (N, m) regressors entering linearly: ẑ += extra β
    weight: np.ndarray | None = None  # (N,) weights of the output error (output forms; input_gain pre-weights)

    @property
    def n_theta(self) -> int:
        return self.order if self.form == "input_gain" else 2 * self.order - (self.form == "output_poly")

    def unpack(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """θ → (a, c) (c None when it is eliminated linearly)."""
        n = self.order
        a = denominator_from_theta(theta[:n], n, self.r_max)
        if self.form == "input_gain":
            return a, None
        a1 = 1.0 + np.sum(a)                       # A(1): c = A(1)·c̃, G(1) = Σ c̃
        ct = theta[n:]
        if self.form == "output_poly":
            ct = np.concatenate([[1.0 - np.sum(ct)], ct])
        return a, a1 * ct

    def solve(self, theta: np.ndarray):
        """(residual on mask, a, c, p, β) with the linear parameters eliminated.

        For ``input_gain`` the regressors are N(u)·Δⁱx₁ (i-th backward differences of
        x₁ = u / A(q), a well-conditioned basis of the same span as x₁(k−i)); c follows by
        the binomial transform."""
        a, c = self.unpack(theta)
        den = np.concatenate([[1.0], a])
        n = self.order
        z = self.z[self.mask]
        if self.form == "input_gain":
            d = signal.lfilter([1.0], den, self.u)
            Phi = self._buffer()
            g = self.gain[self.mask]
            for i in range(n):
                if i:                                   # Δ with x₁ = 0 before the record
                    d = np.concatenate(([d[0]], np.diff(d)))
                np.multiply(g, d[self.mask], out=Phi[:, i])
            k = n
            coef = _linear_ls(Phi, z)
            r = z - Phi @ coef
            beta = coef[k:] if self.extra is not None else None
            return r, a, _binomial(n) @ coef[:k], None, beta
        else:
            y = signal.lfilter(c, den, self.u)
            if self.form == "output_map":
                z = z - _interp_extrap(y[self.mask], *self.table)
                Phi = np.empty((z.size, 0))
            else:
                Phi = np.vander(y[self.mask], self.degree + 1, increasing=True)
        k = Phi.shape[1]
        if self.extra is not None:
            Phi = np.hstack([Phi, self.extra[self.mask]])
        if self.weight is not None:
            w = self.weight[self.mask]
            z = w * z
            Phi = w[:, None] * Phi
        if Phi.shape[1] == 0:
            return z, a, c, None, None
        coef = _linear_ls(Phi, z)
        r = z - Phi @ coef
        beta = coef[k:] if self.extra is not None else None
        if self.form == "input_gain":
            return r, a, _binomial(n) @ coef[:k], None, beta
        return r, a, c, (coef[:k] if self.form == "output_poly" else None), beta

    def _buffer(self) -> np.ndarray:
        """Preallocated regressor matrix [N(u)Δⁱx₁ … | extra] (Fortran order, reused)."""
        if getattr(self, "_phi", None) is None:
            m = 0 if self.extra is None else self.extra.shape[1]
            buf = np.empty((self.z[self.mask].size, self.order + m), order="F")
            if m:
                buf[:, self.order:] = self.extra[self.mask]
            self._phi = buf
        return self._phi

    def full_residual(self, a, c, p, beta) -> np.ndarray:
        y = signal.lfilter(c, np.concatenate([[1.0], a]), self.u)
        zhat = _static(self.form, self.u, y, self.gain, self.table, p)[self.mask]
        if beta is not None:
            zhat = zhat + self.extra[self.mask] @ beta
        return self.z[self.mask] - zhat


def _binomial(n: int) -> np.ndarray:
    """M with c = M·γ when Σ γᵢ Δⁱx(k) = Σ c_j x(k−j): M[j, i] = (−1)ʲ C(i, j)."""
    M = np.zeros((n, n))
    for i in range(n):
        row = np.array([1.0])
        for _ in range(i):
            row = np.convolve(row, [1.0, -1.0])
        M[: i + 1, i] = row
    return M


def _linear_ls(Phi: np.ndarray, z: np.ndarray) -> np.ndarray:
    """argmin ‖z − Φγ‖ by column-scaled normal equations (Φ tall and thin), with an SVD
    fallback when they are ill-conditioned."""
    G = Phi.T @ Phi
    s = np.sqrt(np.diag(G))
    s[s == 0] = 1.0
    Gs = G / np.outer(s, s)
    try:
        coef = np.linalg.solve(Gs, (Phi.T @ z) / s) / s
        if np.all(np.isfinite(coef)) and np.min(np.linalg.eigvalsh(Gs)) > 1e-10:
            return coef
    except np.linalg.LinAlgError:
        pass
    return np.linalg.lstsq(Phi, z, rcond=None)[0]
