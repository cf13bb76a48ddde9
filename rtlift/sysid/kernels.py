"""The identification's two inner loops compiled (numba), each the same arithmetic in the same
order as the code it stands for, so every number is bit for bit the one it replaces
(tests/test_sysid_kernels.py compares the bits):

- :func:`lfilter`: ``scipy.signal.lfilter(b, a, v, axis=0)`` for a recursive filter (``a`` of
  more than one coefficient) on float64 data of :data:`MIN_COLUMNS` or more columns. scipy's
  ``_linear_filter`` pads ``b`` and ``a`` with zeros to one length n, divides both by a₀, and
  runs the direct form II transposed recursion on each column,

      y(k) = z₀ + b₀ x(k),
      zᵢ ← zᵢ₊₁ + x(k) bᵢ₊₁ − y(k) aᵢ₊₁   (i = 0 … n − 3),
      zₙ₋₂ ← x(k) bₙ₋₁ − y(k) aₙ₋₁,

  from rest (z = 0). Here every column takes those steps too, but one sample of all the
  columns at a time (the columns are independent: the same operations per column, run side by
  side in vector registers): 3–5× faster on the refinements' 30 000 × 16–96 bases. The output is
  row-major (C order) like scipy's, so what multiplies it next (BLAS) sees the same layout.
  A filter without recursion (one ``a`` coefficient), a 1-D signal, fewer columns or another
  dtype is handed to scipy.
- :class:`Hats`: the extrapolated piecewise-linear basis of
  :func:`rtlift.sysid.identify._extrapolated_hat_basis`, computed row by row with that
  function's operations in one pass instead of numpy's several, and kept as each row's segment
  and two nonzero values: written out into a zeroed column-major array (:meth:`Hats.basis`) or
  filtered without being written out (:meth:`Hats.filtered`: the recursion of :func:`lfilter`
  on rows that are zero but for those two values, the same steps on the zeros too).

numba is not allowed to contract a product and a sum into one fused multiply-add (no fastmath),
so each operation rounds as scipy's C and numpy do.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from rtlift.core.jit import njit_cached


@njit_cached
def _filter_columns(b: np.ndarray, a: np.ndarray, x: np.ndarray, out: np.ndarray) -> None:   # pragma: no cover
    """The recursion of the module docstring on every column of ``x`` (n × k, any layout) into
    ``out`` (n × k); ``b`` and ``a`` of one length ≥ 2, already divided by a₀."""
    n, k = x.shape
    z = np.zeros((b.size - 1, k))
    xr = np.empty(k)
    for i in range(n):
        for j in range(k):
            xr[j] = x[i, j]
        _step_row(b, a, xr, out[i], z)


@njit_cached
def _step_row(b: np.ndarray, a: np.ndarray, xr: np.ndarray, yr: np.ndarray, z: np.ndarray
              ) -> None:   # pragma: no cover
    """One sample of the recursion on every column: input row ``xr``, output row ``yr``, the
    state ``z`` ((m − 1) × k) advanced in place."""
    k = xr.size
    m = b.size
    for j in range(k):
        yr[j] = z[0, j] + b[0] * xr[j]
    for q in range(m - 2):
        bq = b[q + 1]
        aq = a[q + 1]
        for j in range(k):
            z[q, j] = z[q + 1, j] + xr[j] * bq - yr[j] * aq
    bq = b[m - 1]
    aq = a[m - 1]
    for j in range(k):
        z[m - 2, j] = xr[j] * bq - yr[j] * aq


def _padded(b: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """b and a zero-padded to one length and divided by a₀, as scipy's ``_linear_filter`` does."""
    m = max(a.size, b.size)
    bp, ap = np.zeros(m), np.zeros(m)
    bp[:b.size], ap[:a.size] = b, a
    a0 = ap[0]
    bp /= a0
    ap /= a0
    return bp, ap


MIN_COLUMNS = 8
"""The fewest columns :func:`lfilter` runs side by side; fewer (and 1-D signals) go to scipy, whose
one column at a time is as fast there (30 000 samples, filter orders 2 and 6, loaded 2-core
machine: 2 columns 2.1–2.3 ms in scipy against 2.3–7.6 ms, 8 columns 8–12 against 6–8 ms,
16 columns 18–22 against 4–6 ms)."""


def lfilter(b: np.ndarray, a: np.ndarray, v: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """B(q)/A(q) v along axis 0 from rest: ``scipy.signal.lfilter(b, a, v, axis=0)`` bit for bit
    (module docstring), into ``out`` (C order, v's shape) if given."""
    b = np.asarray(b)
    a = np.asarray(a)
    v = np.asarray(v)
    if (a.ndim != 1 or b.ndim != 1 or a.size < 2 or v.ndim != 2 or v.shape[1] < MIN_COLUMNS or
            not all(t.dtype == np.float64 for t in (a, b, v))):
        y = signal.lfilter(b, a, v, axis=0)
        if out is None:
            return y
        out[...] = y
        return out
    bp, ap = _padded(b, a)
    y = np.empty(v.shape) if out is None else out
    _filter_columns(bp, ap, v, y)
    return y


@njit_cached
def _hat_rows(x: np.ndarray, knots: np.ndarray, inv: np.ndarray, seg: np.ndarray,
              w: np.ndarray) -> None:   # pragma: no cover
    """Row k of Φ from x(k), as its segment s = seg[k] and its two nonzero values w[k] (columns s,
    s + 1): s = (number of knots ≤ x(k)) − 1 clipped to 0 … m − 2, d = x − x_s (x − x_last at or
    above the last knot), and [−d/h_s + 1, d/h_s] (above: [−d/h_s, d/h_s + 1]), as
    :func:`rtlift.sysid.identify._extrapolated_hat_basis` computes them; x(k) equal to the last
    knot: [0, 1]. ``inv`` = 1/h, the knots' reciprocal spacings."""
    last = knots.size - 1
    top = knots[last]
    for r in range(x.size):
        xr = x[r]
        lo, hi = 0, knots.size            # searchsorted(knots, xr, side="right"): knots ≤ xr (NaN: all)
        if xr != xr:
            lo = hi
        while lo < hi:
            mid = (lo + hi) // 2
            if knots[mid] <= xr:
                lo = mid + 1
            else:
                hi = mid
        s = min(max(lo - 1, 0), last - 1)
        seg[r] = s
        if xr == top:
            w[r, 0] = 0.0
            w[r, 1] = 1.0
        elif xr >= top:
            d = xr - top
            w[r, 0] = -inv[s] * d + 0.0
            w[r, 1] = inv[s] * d + 1.0
        else:
            d = xr - knots[s]
            w[r, 0] = -inv[s] * d + 1.0
            w[r, 1] = inv[s] * d + 0.0


@njit_cached
def _scatter(seg: np.ndarray, w: np.ndarray, phi: np.ndarray) -> None:   # pragma: no cover
    """Row k's two values into the zeroed Φ at columns seg[k], seg[k] + 1."""
    for r in range(seg.size):
        phi[r, seg[r]] = w[r, 0]
        phi[r, seg[r] + 1] = w[r, 1]


@njit_cached
def _filter_hats(b: np.ndarray, a: np.ndarray, seg: np.ndarray, w: np.ndarray, out: np.ndarray
                 ) -> None:   # pragma: no cover
    """:func:`_filter_columns` of the basis Φ given by its rows' segments and values (Φ is never
    written out: row k is zero but for w[k] at seg[k], seg[k] + 1, and every column's recursion
    takes the same steps on those zeros as on Φ's)."""
    n, k = out.shape
    z = np.zeros((b.size - 1, k))
    xr = np.zeros(k)
    for i in range(n):
        s = seg[i]
        xr[s] = w[i, 0]
        xr[s + 1] = w[i, 1]
        _step_row(b, a, xr, out[i], z)
        xr[s] = 0.0
        xr[s + 1] = 0.0


class Hats:
    """The basis Φ of :func:`rtlift.sysid.identify._extrapolated_hat_basis` for a float64 x and at
    least two increasing knots, kept as each row's segment and two values (n × 2): Φ itself
    (:meth:`basis`) or Φ filtered (:meth:`filtered`), bit for bit numpy's Φ and scipy's filtering
    of it."""

    def __init__(self, x: np.ndarray, knots: np.ndarray) -> None:
        self.count = knots.size
        self.seg = np.empty(x.size, dtype=np.int64)
        self.w = np.empty((x.size, 2))
        _hat_rows(x, knots, 1.0 / np.diff(knots), self.seg, self.w)

    def basis(self, rows: slice = slice(None)) -> np.ndarray:
        """Φ's ``rows`` (column-major, as numpy's)."""
        seg = self.seg[rows]
        phi = np.zeros((seg.size, self.count), order="F")
        _scatter(seg, self.w[rows], phi)
        return phi

    def filtered(self, b: np.ndarray, a: np.ndarray, out: np.ndarray, rows: slice = slice(None)) -> np.ndarray:
        """B(q)/A(q) Φ[rows] along axis 0 from rest into ``out`` (C order): scipy's ``lfilter`` of
        the column-major Φ, bit for bit (:func:`lfilter`; fewer than :data:`MIN_COLUMNS` columns
        or a filter without recursion: Φ is written out and handed to it)."""
        b, a = np.asarray(b, dtype=float), np.asarray(a, dtype=float)
        if a.size < 2 or self.count < MIN_COLUMNS:
            return lfilter(b, a, self.basis(rows), out)
        bp, ap = _padded(b, a)
        _filter_hats(bp, ap, self.seg[rows], self.w[rows], out)
        return out


