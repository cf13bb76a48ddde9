"""The compiled 400 Hz step and batch of the interaction structure (:mod:`rtlift.blocks.interaction`;
numba, through :func:`rtlift.core.jit.njit_cached`), on the same per-sample helpers as the
hybrid's (:mod:`rtlift.blocks.compiled`):

    ΔCL_H(k) = G_H(m) HF(c)(k) + G(m) (c − HF(c))(k) + S(u) u,   c = φ h ∗ Cμ′
    ΔCL_L(k) = N(u(k)) · C x(k)  (form 0)  or  f(C x(k))  (form 1),   x(k) = A x(k−1) + B u(k)
    u(k) = Cμ_env′(k) · min(1, q(k)/q₀)   or, with a static map,   f(Cμ_env′(k))/s · min(1, q(k)/q₀)^p

with the diagnosis's stages as in the paper's structure (:mod:`rtlift.blocks.compiled_stages`):
a ``delay``, an ``actuator_fade`` and an ``onset_hold`` before the structure's own stage (Cμ′, Cμ_env′), the
``hysteresis`` factor on ΔCL_L and the output stages after the sum.

:func:`interaction_step` is one sample, :func:`interaction_simulate` the batch, both on one
packed copy of the parameters (:func:`pack_interaction`).
"""

from __future__ import annotations

import numpy as np
from numba import carray

from rtlift.blocks.compiled import (
    _highpass,
    _push,
    _recursions_on_stack,
    _scatter_past,
    _segment,
    _stack_buffer,
    _table,
    _table_at,
    _wiener,
    _wiener_table,
)
from rtlift.blocks.compiled_stages import _direction_factor, _output_chain, _staged, _staged_inputs, has_staged_inputs
from rtlift.core.jit import njit_cached


def pack_interaction(par: np.ndarray, envelope_in: tuple[float, float, float],
                     momentum_conv: tuple[float, float, float], knots: np.ndarray, gains_h: np.ndarray,
                     slopes_h: np.ndarray, gains: np.ndarray, slopes: np.ndarray, gains_s: np.ndarray,
                     slopes_s: np.ndarray, lift: tuple[float, float, np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """The interaction structure's fixed numbers: :func:`~rtlift.blocks.compiled.pack_parameters`'
    array (its φh, SOS rows and scratch those of the burst part's convolution and HF), then the
    delivered-envelope stage's (λ, 1 − λ, 1/q₀) and the burst part's own momentum's (λ, 1 − λ,
    1/d), then [K, knots (K), G_H values (K), slopes (K − 1), G values (K), slopes (K − 1), S
    values (K), slopes (K − 1)], then the delivered envelope's static map
    (:meth:`~rtlift.blocks.delivered.DeliveredEnvelope.lift_arrays`): [p, 1/s, L, grid (L),
    N (L), slopes (L − 1)], L = 0 without one."""
    power, inv_chord, grid, gain, gain_slopes = lift
    return np.concatenate([par, envelope_in, momentum_conv, [float(knots.size)], knots, gains_h, slopes_h,
                           gains, slopes, gains_s, slopes_s, [power, inv_chord, float(grid.size)], grid, gain,
                           gain_slopes])


@njit_cached(inline="always")
def _interaction_offset(par, n_taps, n_sections, n):
    """Where :func:`pack_interaction`'s part starts in ``par`` (after the Wiener table and scratch)."""
    return 2 + n_taps + 5 * n_sections + n * n + 2 * n + 3 * int(par[1]) - 1 + n


@njit_cached(inline="always")
def _gain_tables(par, o):
    """Views of the G_H, G and S tables whose length K is ``par[o]``: (knots, G_H, slopes, G,
    slopes, S, slopes)."""
    k = int(par[o])
    o += 1
    return (par[o:o + k], par[o + k:o + 2 * k], par[o + 2 * k:o + 3 * k - 1], par[o + 3 * k - 1:o + 4 * k - 1],
            par[o + 4 * k - 1:o + 5 * k - 2], par[o + 5 * k - 2:o + 6 * k - 2], par[o + 6 * k - 2:o + 7 * k - 3])


@njit_cached(inline="always")
def _lift_table(par, o):
    """(p, 1/s, grid, N, slopes) of the delivered envelope's static map, which starts at
    ``par[o]`` (``o`` the gain tables' start, :func:`_gain_tables`); an empty grid without one."""
    o += 7 * int(par[o]) - 2
    n = int(par[o + 2])
    o += 3
    return par[o - 3], par[o - 2], par[o:o + n], par[o + n:o + 2 * n], par[o + 2 * n:o + 3 * n - 1]


@njit_cached(inline="always")
def _delivered(env, gate, power, inv_chord, grid, gain, slopes):
    """The delivered envelope u (:class:`~rtlift.blocks.delivered.DeliveredEnvelope`): Cμ_env · gate,
    or with the static map f(Cμ_env)/s · gate^p, gate = min(1, q/q₀)."""
    if grid.shape[0] == 0:
        return env * gate
    n = int(power)
    if gate >= 1.0:                           # 1^p: no pow call where bursts fire at the optimal rate
        g = 1.0
    elif n == power and 0 < n <= 8:           # :func:`~rtlift.blocks.delivered.gate_power`'s products
        g = gate
        for _ in range(n - 1):
            g = g * gate
    else:
        g = gate ** power
    return _table(grid, gain, slopes, env, False) * env * inv_chord * g


@njit_cached(inline="always")
def _burst_terms(knots, gh, gh_slopes, g, g_slopes, gs, gs_slopes, m, u, c, hf):
    """The burst part's three terms, G_H(m) HF(c), G(m) (c − HF(c)) and S(u) u: ΔCL_H is their
    sum in this order (the Python step's, :meth:`~rtlift.blocks.interaction.InteractionConvolution.step`),
    the last two its slow term."""
    j = _segment(knots, m)                    # G_H and G share the knots and m: one search
    return (_table_at(knots, gh, gh_slopes, m, False, j) * hf, _table_at(knots, g, g_slopes, m, False, j) * (c - hf),
            _table(knots, gs, gs_slopes, u, False) * u)


@njit_cached(inline="always")
def _momentum(lam, b, inv_d, m, cmu):
    """``m(k) = (1 − λ) Cμ(k)/d + λ m(k−1)`` (:class:`~rtlift.blocks.delivered.DeliveredMomentum`'s order)."""
    return b * (cmu * inv_d) + lam * m


@njit_cached(inline="always")
def _burst_memory(lam, b, q, cmu):
    """``q(k) = (1 − λ) [Cμ(k) > 0] + λ q(k−1)`` (:class:`~rtlift.blocks.delivered.DeliveredEnvelope`'s order)."""
    return b * (1.0 if cmu > 0.0 else 0.0) + lam * q


@njit_cached
def interaction_step(cmu, env, par, d_cmu, d_env, d_pos, fpar, sstate, m_in, buf, pos, z, m_conv, x):
    """One sample of the interaction structure (:mod:`rtlift.blocks.interaction`): (ΔCL, ΔCL_H,
    ΔCL_L); advances the delay rings, the fade's clock, the delivered envelope's memory q (``m_in``,
    the input stage's; u = Cμ_env′ min(1, q/q₀) is the Wiener part's input), the convolution
    buffer, the burst part's HF state z and its m (``m_conv``), the LTI state x, the hysteresis
    factor's and the output stages' states in place (``par``: :func:`pack_interaction`, then
    :func:`~rtlift.blocks.compiled_stages.with_outputs`' tail; ``fpar``/``sstate`` as in
    :func:`~rtlift.blocks.compiled.hybrid_step`)::

        ΔCL_H(k) = G_H(m) HF(c)(k) + [G(m) (c − HF(c))(k) + S(u) u],   c = φ h ∗ Cμ′
        ΔCL_L(k) = N(u(k)) · C x(k)  (form 0)  or  f(C x(k))  (form 1),   x(k) = A x(k−1) + B u(k)

    ΔCL_L times the hysteresis factor g (1 + m h) where the model has one, its lift driver the
    Wiener part plus the bracket (the burst part's slow term); ΔCL after the output stages.
    """
    total, high, low, _, _, _ = interaction_sample(cmu, env, par, d_cmu, d_env, d_pos, fpar, sstate, m_in, buf, pos,
                                                   z, m_conv, x)
    return total, high, low


@njit_cached(inline="always")
def interaction_sample(cmu, env, par, d_cmu, d_env, d_pos, fpar, sstate, m_in, buf, pos, z, m_conv, x):
    """:func:`interaction_step` that also returns what the filter of an observer sees, (ΔCL,
    ΔCL_H, ΔCL_L, Cμ′, u, known): Cμ after the delay and the fade, the delivered envelope u, and
    the flagged output stages' corrections (:func:`~rtlift.blocks.compiled_stages._output_chain`)."""
    cmu, env = _staged(cmu, env, par, d_cmu, d_env, d_pos, fpar, sstate)
    n_taps = buf.shape[0] // 2
    n_sec = z.shape[0] // 2
    n = x.shape[0]
    o = _interaction_offset(par, n_taps, n_sec, n)
    q = _burst_memory(par[o], par[o + 1], m_in[0], cmu)
    m_in[0] = q
    power, inv_chord, lgrid, lgain, lslopes = _lift_table(par, o + 6)
    u = _delivered(env, min(1.0, par[o + 2] * q), power, inv_chord, lgrid, lgain, lslopes)
    p = _push(buf, pos, cmu)
    c = 0.0
    for j in range(n_taps):
        c += par[2 + j] * buf[p + j]
    hf = _highpass(par, 2 + n_taps, z, c)
    mc = _momentum(par[o + 3], par[o + 4], par[o + 5], m_conv[0], cmu)
    m_conv[0] = mc
    knots, gh, gh_slopes, g, g_slopes, gs, gs_slopes = _gain_tables(par, o + 6)
    fast, slow_c, slow_u = _burst_terms(knots, gh, gh_slopes, g, g_slopes, gs, gs_slopes, mc, u, c, hf)
    high = fast + slow_c + slow_u
    slow = slow_c + slow_u
    ow = 2 + n_taps + 5 * n_sec
    xs, fs, slopes, scratch = _wiener_table(par, ow, n)
    low = _direction_factor(_wiener(par, ow, xs, fs, slopes, scratch, x, u), u, par, sstate, slow)
    total, known = _output_chain(high + low, par, sstate)
    return total, high, low, cmu, u, known


@njit_cached
def interaction_simulate(cmu, env, total, high, low, par, d_cmu, d_env, d_pos, fpar, sstate, m_in, buf, pos, z,
                         m_conv, x, z_slots, x_slots, p_slots, i_slots):
    """:func:`interaction_step` over whole arrays in one loop, into ``total``, ``high`` and
    ``low``, from and advancing the same state: the convolution scattered as in
    :func:`~rtlift.blocks.compiled.hybrid_simulate` (same helpers), the HF and LTI states and m
    and q in registers, the output stages after the loop. As there, the recursions' parameters
    and this structure's own (memories, gain tables, static map: ``i_slots`` long) are copied to
    the stack for the loop: read from ``par``, each was loaded again after every store to an
    output (measured on the benchmark record, with the staged inputs' copies and the gate's
    1^p: 21 ms before, 10 ms after); the arithmetic, and so the output, is the same bit for bit."""
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
    o_w = o_hp + 5 * (n_z // 2)
    grid, values, slopes, _ = _wiener_table(par, n_taps + o_w, n_x)
    o = _interaction_offset(par, n_taps, n_z // 2, n_x)
    n_i = len(i_slots)
    ipar = carray(_stack_buffer(i_slots), (n_i,))
    ipar[:] = par[o:o + n_i]
    lam_i, b_i, scale_i, lam_c, b_c, inv_d_c = ipar[0], ipar[1], ipar[2], ipar[3], ipar[4], ipar[5]
    knots, gh, gh_slopes, g, g_slopes, gs, gs_slopes = _gain_tables(ipar, 6)
    power, inv_chord, lgrid, lgain, lslopes = _lift_table(ipar, 6)
    mi, mc = m_in[0], m_conv[0]
    _scatter_past(buf, pos[0], taps, high, n)
    if has_staged_inputs(par, d_cmu, fpar):   # the staged inputs, in place of the outputs
        _staged_inputs(cmu, env, total, low, par, d_cmu, d_env, d_pos, fpar, sstate)
        cmu = total
        env = low                             # each read before its slot is written
    last = n - n_taps
    for k in range(n):
        c = cmu[k]
        if k >= last:                         # as in hybrid_simulate
            _push(buf, pos, c)
        if k + n_taps - 1 < n:
            high[k + n_taps - 1] = 0.0
        if c != 0.0:
            for j in range(min(n_taps, n - k)):
                high[k + j] += taps[j] * c
        conv = high[k]
        hf = _highpass(rec, o_hp, z_local, conv)
        mi = _burst_memory(lam_i, b_i, mi, c)
        u = _delivered(env[k], min(1.0, scale_i * mi), power, inv_chord, lgrid, lgain, lslopes)
        mc = _momentum(lam_c, b_c, inv_d_c, mc, c)
        fast, slow_c, slow_u = _burst_terms(knots, gh, gh_slopes, g, g_slopes, gs, gs_slopes, mc, u, conv, hf)
        h = fast + slow_c + slow_u
        slow = slow_c + slow_u
        lo = _direction_factor(_wiener(rec, o_w, grid, values, slopes, scratch, x_local, u), u, par, sstate, slow)
        high[k] = h
        low[k] = lo
        total[k] = h + lo
    m_in[0] = mi
    m_conv[0] = mc
    z[:] = z_local
    x[:] = x_local
    if par[par.shape[0] - 2] != 0.0:          # the output stages, sample by sample
        for k in range(n):
            total[k], _ = _output_chain(total[k], par, sstate)
