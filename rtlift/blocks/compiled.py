"""The compiled 400 Hz step of the hybrid model (numba, through :func:`rtlift.core.jit.njit_cached`).

:func:`hybrid_step` is :meth:`rtlift.model.hybrid.HybridModel.reference_step` for a model whose
only augmentation stage is at most one input ``delay`` (what ``rtlift identify`` writes), as
one machine-code call on the blocks' own state arrays (their ``kernel_arrays()``, not
copies), so the blocks' ``get_state``/``set_state`` see what it did, and on one packed copy
of their parameters (:func:`pack_parameters`):

    Cμ′(k) = Cμ(k − D), Cμ_env′(k) = Cμ_env(k − D)                     (delay, D ≥ 0)
    ΔCL_H(k) = HF(φ Σ_j h(j) Cμ′(k − j))                ring buffer → SOS, TDF-II (sosfilt's)
    x(k) = A x(k−1) + B Cμ_env′(k),  y(k) = C x(k),  ΔCL_L(k) = N(Cμ_env′(k)) y(k)  or  f(y(k))

It allocates nothing on the heap and touches no Python object; the same recurrences in the same order
as the pure-Python blocks, so the two agree to rounding (the convolution's sum order differs
from BLAS ``ddot``'s). numba compiles on the first call with these argument types, or loads
the machine code from its cache (``__pycache__``) — :meth:`HybridModel.warm_up` does that
before a live link opens.

:func:`hybrid_simulate` is the same model's batch (:meth:`HybridModel.simulate`): one loop over
the samples through the same per-sample helpers (``_delayed``, ``_push``, ``_highpass``,
``_wiener``, inlined), except the convolution, which scatters each non-zero input instead of
taking a dot per output. It is compiled once per size of the filter and LTI states (their
loops unrolled, the states and the recursions' parameters held in registers; a few seconds the
first time, then numba's cache). Measured on the benchmark record (10 min at 400 Hz, 300 taps,
7 % non-zero Cμ): ≈ 2.0 ms, against ≈ 3.7 ms with the states left in the blocks' arrays (every
sample's recursions through memory) and 10–12 ms for the numpy/scipy chain.

The interaction structure's step and batch (:mod:`rtlift.blocks.compiled_interaction`) run on
the same per-sample helpers.
"""

from __future__ import annotations

import numpy as np
from numba import carray, types
from numba.core import cgutils
from numba.extending import intrinsic

from rtlift.blocks.compiled_stages import _direction_factor, _output_chain, _staged, _staged_inputs, has_staged_inputs
from rtlift.core.jit import njit_cached

_COUNT_MAX = 128
"""Grids up to this many points are searched by counting (:func:`_segment`)."""


@njit_cached(inline="always")
def _segment(xs, v):
    """``bisect_right(xs, v) − 1``: the grid segment holding v (−1 below the grid). A grid of up
    to ``_COUNT_MAX`` points is searched by counting the points v is not below: the same number
    for every v (NaN included) on a strictly increasing grid, and no branch to mispredict —
    measured 0.29 against 1.45 ms for 240 000 lookups in 8 points, 0.49 against 3.4 ms in 25,
    1.2 against 6.2 ms in 96 (bisection, kept for longer grids)."""
    n = xs.shape[0]
    if n <= _COUNT_MAX:
        count = 0
        for i in range(n):
            count += not v < xs[i]
        return count - 1
    lo, hi = 0, n
    while lo < hi:
        mid = (lo + hi) // 2
        if v < xs[mid]:
            hi = mid
        else:
            lo = mid + 1
    return lo - 1


@njit_cached(inline="always")
def _table(xs, fs, slopes, v, extrapolate):
    """The piecewise-linear table of :class:`rtlift.blocks.wiener._Table` (bisect_right search)."""
    return _table_at(xs, fs, slopes, v, extrapolate, _segment(xs, v))


@njit_cached(inline="always")
def _table_at(xs, fs, slopes, v, extrapolate, j):
    """:func:`_table` in segment ``j`` (``_segment(xs, v)``, found once for tables on one grid)."""
    last = xs.shape[0] - 1
    if j < 0:
        if extrapolate:
            return slopes[0] * (v - xs[0]) + fs[0]
        return fs[0]
    if j >= last:
        if v == xs[last] or not extrapolate:
            return fs[last]
        return slopes[last - 1] * (v - xs[last]) + fs[last]
    return slopes[j] * (v - xs[j]) + fs[j]


def pack_parameters(taps: np.ndarray, coef: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray,
                    form: int, xs: np.ndarray, fs: np.ndarray, slopes: np.ndarray) -> np.ndarray:
    """The fixed numbers of one model in one array (one argument instead of nine; each array
    argument costs the numba dispatcher ≈ 45 ns): [form, table length, φh, SOS rows
    (b₀ b₁ b₂ a₁ a₂), A (row-major), B, C, table grid, values, slopes, scratch (n)].
    The lengths of φh, the sections and A follow from the state arrays' lengths."""
    head = np.array([float(form), float(xs.size)])
    return np.concatenate([head, taps, coef.ravel(), A.ravel(), B, C, xs, fs, slopes, np.zeros(B.size)])


@njit_cached(inline="always")
def _push(buf, pos, u):
    """Cμ(k) into the convolution's mirrored buffer; returns the position p of the newest input
    (the last L inputs, newest first, are ``buf[p:p + L]``)."""
    n_taps = buf.shape[0] // 2
    p = pos[0] - 1
    if p < 0:
        p = n_taps - 1
    pos[0] = p
    buf[p] = u
    buf[p + n_taps] = u
    return p


@njit_cached(inline="always")
def _highpass(par, o, z, v):
    """One sample through the SOS cascade (TDF-II, sosfilt's recurrences) whose rows start at
    ``par[o]``; advances z."""
    for s in range(z.shape[0] // 2):
        y = par[o] * v + z[2 * s]
        z[2 * s] = par[o + 1] * v - par[o + 3] * y + z[2 * s + 1]
        z[2 * s + 1] = par[o + 2] * v - par[o + 4] * y
        v = y
        o += 5
    return v


@njit_cached(inline="always")
def _wiener_table(par, o, n):
    """Views of ``par`` for the Wiener block of order n whose A starts at ``par[o]``: the table's
    (grid, values, slopes) and the LTI's scratch. Taken once per call, not per sample: each view
    costs two atomic reference counts (≈ 40 ns for the four in a loop over samples)."""
    o += n * n + 2 * n
    n_table = int(par[1])
    return (par[o:o + n_table], par[o + n_table:o + 2 * n_table], par[o + 2 * n_table:o + 3 * n_table - 1],
            par[o + 3 * n_table - 1:o + 3 * n_table - 1 + n])


@njit_cached(inline="always")
def _wiener(par, o, xs, fs, slopes, scratch, x, env):
    """ΔCL_L(k) of the Wiener block whose A starts at ``par[o]`` (then B, C; the table's views
    from :func:`_wiener_table`); advances x."""
    n = x.shape[0]
    b, c_ = o + n * n, o + n * n + n
    for i in range(n):
        acc = par[b + i] * env
        for j in range(n):
            acc += par[o + i * n + j] * x[j]
        scratch[i] = acc
    y = 0.0
    for i in range(n):
        x[i] = scratch[i]
        y += par[c_ + i] * scratch[i]
    if par[0] == 0.0:
        return _table(xs, fs, slopes, env, False) * y
    return _table(xs, fs, slopes, y, True)


@njit_cached
def hybrid_step(cmu, env, par, d_cmu, d_env, d_pos, fpar, sstate, buf, pos, z, x):
    """One sample: (ΔCL, ΔCL_H, ΔCL_L); advances the delay rings, the fade's clock, the
    convolution buffer and position, the filter state z, the LTI state x and the output stages'
    states in place (``par``: :func:`pack_parameters`, then the output stages',
    :func:`~rtlift.blocks.compiled_stages.with_outputs`). ``d_cmu``/``d_env`` are the ``delay``
    stage's rings (length D; empty: no delay), ``fpar`` the ``actuator_fade`` stage's parameters
    after it and ``sstate`` its clock, then the output stages' states, then the ``onset_hold``
    stage's (:func:`~rtlift.blocks.compiled_stages.bind_stage_states`; its place in ``par``'s tail,
    :func:`~rtlift.blocks.compiled_stages._staged`).
    Form 0: ΔCL_L = N(Cμ_env) · y (paper, table held at its ends); 1: ΔCL_L = f(y) (textbook,
    table continued along its end segments). ΔCL is after the output stages, ΔCL_H and ΔCL_L
    before them.
    """
    total, high, low, _, _, _ = hybrid_sample(cmu, env, par, d_cmu, d_env, d_pos, fpar, sstate, buf, pos, z, x)
    return total, high, low


@njit_cached(inline="always")
def hybrid_sample(cmu, env, par, d_cmu, d_env, d_pos, fpar, sstate, buf, pos, z, x):
    """:func:`hybrid_step` that also returns the inputs after the input stages and the flagged
    output stages' corrections, (ΔCL, ΔCL_H, ΔCL_L, Cμ′, Cμ_env′, known): what the observer's
    step needs besides the output."""
    cmu, env = _staged(cmu, env, par, d_cmu, d_env, d_pos, fpar, sstate)
    p = _push(buf, pos, cmu)
    n_taps = buf.shape[0] // 2
    v = 0.0
    for j in range(n_taps):
        v += par[2 + j] * buf[p + j]              # φh starts after [form, table length]
    high = _highpass(par, 2 + n_taps, z, v)
    o = 2 + n_taps + 5 * (z.shape[0] // 2)
    xs, fs, slopes, scratch = _wiener_table(par, o, x.shape[0])
    low = _direction_factor(_wiener(par, o, xs, fs, slopes, scratch, x, env), env, par, sstate, 0.0)
    total, known = _output_chain(high + low, par, sstate)
    return total, high, low, cmu, env, known


@njit_cached(inline="always")
def _scatter_past(buf, p, taps, out, n):
    """The batch convolution's start: zero ``out[:L − 1]`` and scatter the inputs still in the
    ring buffer (``buf[p + i]`` = Cμ′(−1 − i) reaches outputs 0 … L − 2 − i) into it."""
    n_taps = taps.shape[0]
    for m in range(min(n, n_taps - 1)):
        out[m] = 0.0
    for i in range(n_taps - 1):
        u = buf[p + i]
        if u != 0.0:
            for m in range(min(n_taps - 1 - i, n)):
                out[m] += taps[m + i + 1] * u


@intrinsic
def _stack_buffer(typingctx, like):
    """A float64 buffer on the stack as long as the tuple ``like``, whose length is part of its
    type: one compiled batch per state size, whose loops over the state LLVM unrolls and whose
    state it then holds in registers (``like`` of another type: not typed)."""
    if not isinstance(like, types.UniTuple):
        return None

    def codegen(context, builder, signature, args):
        return cgutils.alloca_once(builder, context.get_value_type(types.float64), size=like.count)

    return types.CPointer(types.float64)(like), codegen


def state_slots(z: np.ndarray, x: np.ndarray) -> tuple[tuple[float, ...], ...]:
    """The size arguments of :func:`hybrid_simulate` for the filter state z, the LTI state x
    and the parameters of both recursions ([form, table length, SOS rows, A, B, C])."""
    return (0.0,) * z.size, (0.0,) * x.size, (0.0,) * (2 + 5 * (z.size // 2) + x.size * (x.size + 2))


@njit_cached(inline="always")
def _recursions_on_stack(par, n_taps, p_slots):
    """A stack copy of the recursions' parameters, ``par`` without φh and the table: [form,
    table length, SOS rows, A, B, C] (``p_slots`` long, :func:`state_slots`). The batches read
    them from it in their loops (:func:`hybrid_simulate`'s docstring); inlined, so the buffer
    lives in the caller's frame."""
    n_p = len(p_slots)
    rec = carray(_stack_buffer(p_slots), (n_p,))
    rec[0] = par[0]
    rec[1] = par[1]
    rec[2:] = par[2 + n_taps:n_taps + n_p]
    return rec


@njit_cached
def hybrid_simulate(cmu, env, total, high, low, par, d_cmu, d_env, d_pos, fpar, sstate, buf, pos, z, x, z_slots,
                    x_slots, p_slots):
    """:func:`hybrid_step` over whole arrays in one loop, into ``total``, ``high`` and ``low``
    (same length as ``cmu``), from and advancing the same state, through the same helpers.

    The convolution scatters each non-zero Cμ′(k) over the outputs it reaches,
    ``high[k + j] += φh(j) Cμ′(k)``, with ``high`` itself as the accumulator (nnz·L
    multiply-adds instead of N·L: a burst-modulated Cμ is zero between bursts); the inputs still
    in the ring buffer are scattered first, and the last L inputs are pushed into it, so
    streaming continues where the batch stops. The same products as the step's dot, summed
    oldest input first: equal to rounding. The filter and LTI states are copied to stack
    buffers sized by ``z_slots``/``x_slots`` (:func:`state_slots`) for the loop and back after
    it, and the recursions' parameters to one sized by ``p_slots``: in the blocks' arrays every
    sample's recursions went through memory, and every store to an output array made the
    parameters be loaded again (measured on the benchmark record: 3.7 ms, 2.3 ms with the
    states on the stack, ≈ 2.0 ms with the parameters too); the arithmetic, and so the output,
    is the same bit for bit.
    """
    n = cmu.shape[0]
    n_taps = buf.shape[0] // 2
    n_z, n_x = len(z_slots), len(x_slots)
    z_local = carray(_stack_buffer(z_slots), (n_z,))
    x_local = carray(_stack_buffer(x_slots), (n_x,))
    scratch = carray(_stack_buffer(x_slots), (n_x,))
    z_local[:] = z
    x_local[:] = x
    rec = _recursions_on_stack(par, n_taps, p_slots)
    taps = par[2:2 + n_taps]
    o_hp = 2
    o_wiener = o_hp + 5 * (n_z // 2)
    grid, values, slopes, _ = _wiener_table(par, n_taps + o_wiener, n_x)
    _scatter_past(buf, pos[0], taps, high, n)
    if has_staged_inputs(par, d_cmu, fpar):   # the staged inputs, in place of the outputs
        _staged_inputs(cmu, env, total, low, par, d_cmu, d_env, d_pos, fpar, sstate)
        cmu, env = total, low
    last = n - n_taps
    for k in range(n):
        c, e = cmu[k], env[k]
        if k >= last:                         # the convolution: written out, not a helper (inlined,
            _push(buf, pos, c)                # one took twice the time: 8 against 4 ms here)
        if k + n_taps - 1 < n:
            high[k + n_taps - 1] = 0.0
        if c != 0.0:
            for j in range(min(n_taps, n - k)):
                high[k + j] += taps[j] * c
        h = _highpass(rec, o_hp, z_local, high[k])
        lo = _direction_factor(_wiener(rec, o_wiener, grid, values, slopes, scratch, x_local, e), e, par, sstate,
                               0.0)
        high[k] = h
        low[k] = lo
        total[k] = h + lo
    z[:] = z_local
    x[:] = x_local
    if par[par.shape[0] - 2] != 0.0:          # the output stages, sample by sample
        for k in range(n):
            total[k], _ = _output_chain(total[k], par, sstate)


@njit_cached
def fir_scatter(ext, taps, out):
    """``out = np.convolve(ext, taps, 'valid')`` by scattering each non-zero input over the
    outputs it reaches (``out[i − L + 1 + j] += ext[i] · taps[j]``): nnz(ext)·L multiply-adds
    instead of N·L. The same products as the ring buffer's dot, summed in input order; for the
    burst-modulated Cμ, zero between bursts, ≈ 0.6 of an overlap-add FFT's time."""
    n_taps = taps.shape[0]
    n_out = out.shape[0]
    out[:] = 0.0
    for i in range(ext.shape[0]):
        v = ext[i]
        if v != 0.0:
            j0 = max(0, n_taps - 1 - i)
            j1 = min(n_taps, n_out + n_taps - 1 - i)
            base = i - n_taps + 1
            for j in range(j0, j1):
                out[base + j] += v * taps[j]
