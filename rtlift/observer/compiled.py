"""The compiled 400 Hz observer step (numba, through :func:`rtlift.core.jit.njit_cached`).

:func:`observer_step` is :meth:`rtlift.observer.Observer.reference_step` as one machine-code
call, for an observer whose model takes the compiled model step (``model.compiled``): it calls
the model's own :func:`rtlift.blocks.compiled.hybrid_step` on the model's state arrays, then
runs the filter of :mod:`rtlift.observer` on the observer's arrays (ξ, P, H, the scalar state
``s``), all preallocated and advanced in place, so ``get_state``/``set_state`` and the
reference step see what it did. F is block diagonal and mostly identity: F P Fᵀ runs on its
non-zeros (compressed rows), ≈ 2·nnz(F)·dim_x multiply-adds instead of 2·dim_x³. The
recurrences are the reference step's in the same order, so the two agree to rounding.
:func:`observer_step_interaction` is the same for a model of the ``interaction`` structure: its
own compiled sample (:func:`rtlift.blocks.compiled_interaction.interaction_sample`), then the one
filter both share (:func:`_filter`).

The scalar state ``s`` (float64) is shared with the reference step; its slots are the
constants below. numba compiles on the first call (≈ seconds) or loads the machine code from
its cache: :meth:`Observer.warm_up` does that before a live link opens.
"""

from __future__ import annotations

import math

import numpy as np

from rtlift.blocks.compiled import _segment, _table, hybrid_sample
from rtlift.blocks.compiled_interaction import interaction_sample
from rtlift.blocks.compiled_stages import direction_gain
from rtlift.core.jit import njit_cached
from rtlift.observer import config

# slots of the scalar state s
REJECTED_RUN, GATE_OPEN, LAST_CMU, LAST_ENV, RIPPLE_ON, SAMPLE = 0, 1, 2, 3, 4, 5
UPDATES, REJECTED, MISSING, BAD_INPUTS, NIS_SUM, NIS_IN_BAND, NLL_SUM = 6, 7, 8, 9, 10, 11, 12
TABLE_PERIOD = 13          # the burst period whose basis rows ``tab`` holds (0: none)
PHASE = 14                 # [Cμ(k−1), φ(k), P(k)] of the BurstPhase: s[14:17]
SCALAR_STATE_SIZE = 17

NIS_LOW, NIS_HIGH = config.NIS_BAND

# slots of the integer parameters ipar
DIM_X, N_WIENER, BIAS, GAIN_H, RIPPLE_START, HARMONICS, POWERS, MAX_PERIOD, FORM, NNZ = range(10)
F_ROWS = 10                # then F's row pointers (dim_x + 1) and column indices (nnz)


def pack_layout(layout, R: float, gate: float, max_rejections: int) -> tuple[np.ndarray, np.ndarray]:
    """The fixed numbers of one observer: ``ipar`` (int64: sizes, indices, F's sparsity) and
    ``fpar`` (float64: R, the gate, max_rejections, Cμ_ref, F's non-zeros, G, C, h_lift)."""
    F = layout.F
    rows, cols = np.nonzero(F)
    ptr = np.searchsorted(rows, np.arange(F.shape[0] + 1))
    head = [layout.dim_x, layout.n_wiener, layout.bias, layout.gain_h, layout.ripple_start,
            layout.harmonics, layout.powers, layout.max_period, 0 if layout.form == "input_gain" else 1,
            rows.size]
    ipar = np.concatenate([np.array(head, dtype=np.int64), ptr.astype(np.int64), cols.astype(np.int64)])
    fpar = np.concatenate([[R, gate, float(max_rejections), layout.cmu_ref], F[rows, cols],
                           layout.G, layout.C, layout.h_lift])
    return ipar, fpar


@njit_cached
def observer_step(cmu, env, dcl, mpar, d_cmu, d_env, d_pos, fade_par, sstate, buf, pos, z, xm,
                  ipar, fpar, Q, xi, P, H, T, work, tab, s):
    """One sample (Cμ, Cμ_env, measured ΔCL or NaN): returns (ΔĈL, open-loop ΔCL, ν, NIS,
    flags, b̂). ``mpar … xm``: the model's compiled step and its state (``HybridModel``'s
    binding); ``ipar``/``fpar``: :func:`pack_layout`; ``Q`` the process noise; ``xi``, ``P``,
    ``H`` the state, covariance and measurement row; ``T`` (dim_x²) and ``work`` (2 dim_x)
    scratch; ``tab`` the basis rows of the current burst period; ``s`` the scalar state."""
    cmu, env, dcl, flags = _checked_inputs(cmu, env, dcl, s)
    # the model's step, the inputs its delay and fade stages hand on (Cμ′, Cμ_env′), and the
    # corrections of the output stages the filter does not carry as states (the flags in ``mpar``)
    total, high, _, cmu, env, corrections = hybrid_sample(cmu, env, mpar, d_cmu, d_env, d_pos, fade_par, sstate, buf,
                                                          pos, z, xm)
    return _filter(cmu, env, dcl, flags, total, high, high + corrections, direction_gain(mpar, sstate), mpar,
                   buf.shape[0] // 2, z.shape[0] // 2, ipar, fpar, Q, xi, P, H, T, work, tab, s)


@njit_cached
def observer_step_interaction(cmu, env, dcl, mpar, d_cmu, d_env, d_pos, fade_par, sstate, m_in, buf, pos, z, m_conv,
                              xm, ipar, fpar, Q, xi, P, H, T, work, tab, s):
    """:func:`observer_step` for a model of the ``interaction`` structure (its binding's
    arguments, :func:`rtlift.blocks.compiled_interaction.interaction_step`'s): the same filter, on
    Cμ′ and the delivered envelope u the model's Wiener part sees."""
    cmu, env, dcl, flags = _checked_inputs(cmu, env, dcl, s)
    total, high, _, cmu, env, corrections = interaction_sample(cmu, env, mpar, d_cmu, d_env, d_pos, fade_par, sstate,
                                                               m_in, buf, pos, z, m_conv, xm)
    return _filter(cmu, env, dcl, flags, total, high, high + corrections, direction_gain(mpar, sstate), mpar,
                   buf.shape[0] // 2, z.shape[0] // 2, ipar, fpar, Q, xi, P, H, T, work, tab, s)


@njit_cached(inline="always")
def _checked_inputs(cmu, env, dcl, s):
    """(Cμ, Cμ_env, ΔCL, flags): a non-finite input is replaced by the last good one, its
    measurement by NaN, and counted."""
    flags = 0
    if -math.inf < cmu < math.inf and -math.inf < env < math.inf:
        s[LAST_CMU] = cmu
        s[LAST_ENV] = env
    else:
        cmu, env, dcl = s[LAST_CMU], s[LAST_ENV], math.nan
        flags = config.FLAG_BAD_INPUT
        s[BAD_INPUTS] += 1
    return cmu, env, dcl, flags


@njit_cached(inline="always")
def _filter(cmu, env, dcl, flags, total, high, known, factor, mpar, n_taps, n_sections, ipar, fpar, Q, xi, P, H, T,
            work, tab, s):
    """The filter's predict and update after the model's step (:func:`observer_step`): ``cmu``,
    ``env`` the inputs after the model's input stages, ``total`` the open-loop ΔCL, ``high`` its
    burst part, ``known`` the part of ẑ carried by no state, ``factor`` the Wiener gain's
    hysteresis factor in force (1 without one)."""
    s[SAMPLE] += 1

    d, n = ipar[DIM_X], ipar[N_WIENER]
    nnz = ipar[NNZ]
    ptr = ipar[F_ROWS:F_ROWS + d + 1]
    col = ipar[F_ROWS + d + 1:F_ROWS + d + 1 + nnz]
    R, gate, max_rej, cmu_ref = fpar[0], fpar[1], fpar[2], fpar[3]
    Fv = fpar[4:4 + nnz]
    G = fpar[4 + nnz:4 + nnz + d]
    C = fpar[4 + nnz + d:4 + nnz + d + n]
    h_lift = fpar[4 + nnz + d + n:4 + nnz + 2 * d + n]
    t = work[:d]
    u = work[d:2 * d]

    # predict: ξ⁻ = F ξ + G u,  P⁻ = F P Fᵀ + Q   (F by its non-zeros)
    for i in range(d):
        acc = 0.0
        for k in range(ptr[i], ptr[i + 1]):
            acc += Fv[k] * xi[col[k]]
        t[i] = acc
    for i in range(d):
        xi[i] = t[i] + env * G[i]
    for i in range(d):
        for j in range(d):
            T[i, j] = 0.0
        for k in range(ptr[i], ptr[i + 1]):
            f = Fv[k]
            c = col[k]
            for j in range(d):
                T[i, j] += f * P[c, j]
    for i in range(d):
        for j in range(d):
            acc = 0.0
            for k in range(ptr[j], ptr[j + 1]):
                acc += T[i, col[k]] * Fv[k]
            P[i, j] = acc + Q[i, j]

    # measurement row H(k) and prediction ẑ⁻
    n_table = int(mpar[1])
    o = _table_offset(mpar, n_taps, n_sections, n)
    xs = mpar[o:o + n_table]
    fs = mpar[o + n_table:o + 2 * n_table]
    slopes = mpar[o + 2 * n_table:o + 3 * n_table - 1]
    if ipar[FORM] == 0:
        g = _table(xs, fs, slopes, env, False) * factor
        c0 = 0.0
    else:
        y = 0.0
        for i in range(n):
            y += C[i] * xi[i]
        g = _slope(xs, slopes, y) * factor
        c0 = _table(xs, fs, slopes, y, True) * factor - g * y
    for i in range(n):
        H[i] = g * C[i]
    ig = ipar[GAIN_H]
    if ig >= 0:
        H[ig] = high
    r0, nh = ipar[RIPPLE_START], ipar[HARMONICS]
    if nh > 0:
        row = _phase_step(cmu, s, nh, ipar[MAX_PERIOD], tab)
        if row >= 0:
            w = env
            for p in range(ipar[POWERS]):
                base = r0 + p * 2 * nh
                for j in range(2 * nh):
                    H[base + j] = w * tab[row, j]
                w = w * env / cmu_ref
            s[RIPPLE_ON] = 1.0
        elif s[RIPPLE_ON] != 0.0:
            for j in range(r0, d):
                H[j] = 0.0
            s[RIPPLE_ON] = 0.0
    acc = 0.0
    for i in range(d):
        acc += H[i] * xi[i]
    zhat = known + c0 + acc

    innovation = math.nan
    nis = math.nan
    if not -math.inf < dcl < math.inf:
        flags |= config.FLAG_MISSING
        s[MISSING] += 1
    else:
        nu = dcl - zhat
        for i in range(d):               # P⁻Hᵀ
            acc = 0.0
            for j in range(d):
                acc += P[i, j] * H[j]
            u[i] = acc
        acc = 0.0
        for i in range(d):
            acc += H[i] * u[i]
        S = acc + R
        nis = nu * nu / S
        innovation = nu
        outside = nis > gate
        if outside and s[GATE_OPEN] == 0.0 and s[REJECTED_RUN] < max_rej:
            flags |= config.FLAG_REJECTED
            s[REJECTED] += 1
            s[REJECTED_RUN] += 1
        else:
            if outside:
                flags |= config.FLAG_GATE_RELEASED
                s[GATE_OPEN] = 1.0
                s[REJECTED_RUN] = max_rej
            elif s[REJECTED_RUN] != 0.0:
                s[REJECTED_RUN] = max(s[REJECTED_RUN] - config.GATE_LEAK, 0.0)
                s[GATE_OPEN] = 1.0 if (s[GATE_OPEN] != 0.0 and s[REJECTED_RUN] > 0) else 0.0
            s[UPDATES] += 1
            s[NIS_SUM] += nis
            s[NLL_SUM] += math.log(S) + nis
            if NIS_LOW <= nis <= NIS_HIGH:
                s[NIS_IN_BAND] += 1
            # ξ = ξ⁻ + K ν, K = P⁻Hᵀ/S;  Joseph form with this K: P = P⁻ − w wᵀ, w = P⁻Hᵀ/√S
            a = nu / S
            for i in range(d):
                xi[i] = xi[i] + a * u[i]
            r = 1.0 / math.sqrt(S)
            for i in range(d):
                u[i] = r * u[i]
            for j in range(d):
                uj = -u[j]
                for i in range(d):
                    P[j, i] += u[i] * uj

    y = 0.0
    for i in range(n):
        y += C[i] * xi[i]
    if ipar[FORM] == 0:
        wiener = g * y
    else:
        wiener = _table(xs, fs, slopes, y, True) * factor
    acc = 0.0
    for i in range(d):
        acc += h_lift[i] * xi[i]
    est = known + wiener + acc
    if s[RIPPLE_ON] != 0.0:
        acc = 0.0
        for i in range(r0, d):
            acc += H[i] * xi[i]
        est += acc
    if ig >= 0:
        est += high * xi[ig]
    return est, total, innovation, nis, flags, xi[ipar[BIAS]]


@njit_cached
def _touch(a):
    """Σ of one float per 64-byte cache line of a C-contiguous array (any rank, read only)."""
    flat = a.reshape(a.size)
    acc = 0.0
    for i in range(0, flat.size, 8):
        acc += flat[i]
    return acc


@njit_cached
def observer_touch(mpar, d_cmu, d_env, d_pos, fade_par, sstate, buf, pos, z, xm, ipar, fpar, Q, xi, P, H, T,
                   work, tab, s):
    """Read every cache line :func:`observer_step` will read or write (same arguments after
    Cμ, Cμ_env, ΔCL), changing nothing: called while a spinning loop waits for the next
    sample, it keeps the step's working set (three dim_x² matrices, 22 kB at 30 states) in the
    core's cache, so the step does not start by fetching it from memory."""
    return (_touch(mpar) + _touch(d_cmu) + _touch(d_env) + _touch(d_pos) + _touch(fade_par) + _touch(sstate)
            + _touch(buf) + _touch(pos)
            + _touch(z) + _touch(xm) + _touch(ipar) + _touch(fpar) + _touch(Q) + _touch(xi) + _touch(P)
            + _touch(H) + _touch(T) + _touch(work) + _touch(tab) + _touch(s))


@njit_cached
def observer_touch_interaction(mpar, d_cmu, d_env, d_pos, fade_par, sstate, m_in, buf, pos, z, m_conv, xm, ipar,
                               fpar, Q, xi, P, H, T, work, tab, s):
    """:func:`observer_touch` for :func:`observer_step_interaction`'s arguments."""
    return (observer_touch(mpar, d_cmu, d_env, d_pos, fade_par, sstate, buf, pos, z, xm, ipar, fpar, Q, xi, P, H, T,
                           work, tab, s)
            + _touch(m_in) + _touch(m_conv))


@njit_cached
def _table_offset(mpar, n_taps, n_sections, n):
    """Where the Wiener table starts in :func:`rtlift.blocks.compiled.pack_parameters`'s array."""
    return 2 + n_taps + 5 * n_sections + n * n + 2 * n


@njit_cached
def _slope(xs, slopes, y):
    """df/dy of the table at y: the slope of the segment holding y, the end ones beyond the grid
    (``OutputNonlinearity.slope_at``)."""
    return slopes[min(max(_segment(xs, y), 0), xs.shape[0] - 2)]


@njit_cached
def _phase_step(cmu, s, harmonics, max_period, tab):
    """:meth:`BurstPhase.step` on ``s[PHASE:PHASE + 3]``: the row of ``tab`` at φ(k), or −1
    where undefined; rebuilds ``tab`` when the period changes."""
    since = int(s[PHASE + 1])
    if cmu > 0.0 and not s[PHASE] > 0.0:
        if since >= 0:
            interval = since + 1
            s[PHASE + 2] = interval if 2 * harmonics < interval <= max_period else 0
        since = 0
    elif since >= 0:
        since += 1
    s[PHASE] = cmu
    s[PHASE + 1] = since
    period = int(s[PHASE + 2])
    if period and since < period:
        if int(s[TABLE_PERIOD]) != period:
            for phi in range(period):
                for h in range(1, harmonics + 1):
                    ang = 2.0 * math.pi * (float(phi) * float(h)) / period
                    tab[phi, h - 1] = math.cos(ang)
                    tab[phi, harmonics + h - 1] = math.sin(ang)
            s[TABLE_PERIOD] = period
        return since
    return -1
