"""The effect stages' compiled forms, inlined into the compiled model and observer steps
(:mod:`rtlift.blocks.compiled`, :mod:`rtlift.observer.compiled`).

Input stages, each on its own arrays (the stage's ``kernel_arrays()``, not copies):

    delay            Cμ′(k) = Cμ(k − D), Cμ_env′(k) = Cμ_env(k − D)                 (:func:`_delayed`)
    actuator_fade    g(k) = f + (1 − f) exp(−E(k)/τ),  (Cμ′, Cμ_env′) = g (Cμ, Cμ_env)   (:func:`_faded`)

Output stages, any number in any order, each in the state-space form every output stage states
(:meth:`rtlift.blocks.stage.OutputStage.statespace`, the paper's timing), on the stage's own state:

    x(k) = A x(k−1) + B u(k),   out(k) = C x(k) + D u(k),   u = the ΔCL the stage receives

(``zero_drift``, ``sensor_resonance``, ``periodic_disturbance``; :func:`_output_chain`). Their
parameters are packed in one array (:func:`pack_outputs`) and their states are views into one
array (:func:`bind_output_states`), so the stages' own ``get_state``/``set_state`` and Python
``step`` see what the compiled step did. The recurrences are the stages' own up to the order of
the additions, so the compiled and the Python chains agree to rounding.
"""

from __future__ import annotations

import math

import numpy as np

from rtlift.core.jit import njit_cached


@njit_cached(inline="always")
def _delayed(cmu, env, d_cmu, d_env, d_pos):
    """The ``delay`` stage: (Cμ(k − D), Cμ_env(k − D)) out of its rings (length D; empty: D = 0),
    (Cμ(k), Cμ_env(k)) in."""
    n_delay = d_cmu.shape[0]
    if n_delay == 0:
        return cmu, env
    i = d_pos[0]
    c, e = d_cmu[i], d_env[i]
    d_cmu[i] = cmu
    d_env[i] = env
    d_pos[0] = i + 1 if i + 1 < n_delay else 0
    return c, e


@njit_cached(inline="always")
def _faded(cmu, env, fpar, fstate):
    """The ``actuator_fade`` stage (:class:`rtlift.blocks.actuator_fade.ActuatorFade`):
    (g Cμ, g Cμ_env), E advanced by 1/fs when Cμ > 0 (or always, clock "time"). ``fpar`` =
    [on, f, τ, 1/fs, clock is "time"] (on = 0: no stage), ``fstate`` = [E]."""
    if fpar[0] == 0.0:
        return cmu, env
    f = fpar[1]
    g = f + (1.0 - f) * math.exp(-fstate[0] / fpar[2])
    if cmu > 0.0 or fpar[4] != 0.0:
        fstate[0] = fstate[0] + fpar[3]
    return cmu * g, env * g


def pack_outputs(stages) -> np.ndarray:
    """The output stages' parameters in one array: [count, scratch offset, then per stage
    n, counts toward the observer's known part (1.0; see :func:`_output_chain`), D, A (row-major),
    B, C], then n_max scratch floats."""
    parts = [np.zeros(2)]
    n_max = 0
    for st in stages:
        A, B, C, D = (np.asarray(v, dtype=float) for v in st.statespace())
        n = B.size
        n_max = max(n_max, n)
        parts.append(np.concatenate([[float(n), 1.0, float(D)], A.reshape(n * n), B, C]))
    opar = np.concatenate(parts + [np.zeros(max(n_max, 1))])
    opar[0] = float(len(stages))
    opar[1] = float(opar.size - max(n_max, 1))
    return opar


def output_flags(opar: np.ndarray, known: list[bool]) -> np.ndarray:
    """A copy of ``opar`` whose per-stage flags say which stages' corrections count toward the
    observer's known part of the output (those it does not carry as states)."""
    out = opar.copy()
    o = 2
    for flag in known:
        n = int(out[o])
        out[o + 1] = 1.0 if flag else 0.0
        o += 3 + n * n + 2 * n
    if int(out[0]) != len(known):
        raise ValueError(f"{len(known)} flags for {int(out[0])} output stages")
    return out


def bind_output_states(stages) -> np.ndarray:
    """One array holding every output stage's state, each stage's own state array made a view
    into it (its current state copied in first), for the compiled chain to advance in place."""
    sizes = [int(st.state_size) for st in stages]
    state = np.zeros(max(sum(sizes), 1))
    o = 0
    for st, n in zip(stages, sizes, strict=True):
        view = state[o:o + n]
        view[:] = st.get_state()
        st.adopt_state(view)
        o += n
    return state


@njit_cached(inline="always")
def _output_chain(u, opar, ostate):
    """ΔCL through the output stages packed in ``opar`` (:func:`pack_outputs`), advancing
    ``ostate``: (ΔCL after them, the sum of the flagged stages' corrections out − u)."""
    count = int(opar[0])
    known = 0.0
    if count == 0:
        return u, known
    scr = int(opar[1])
    o = 2
    xo = 0
    for _ in range(count):
        n = int(opar[o])
        a = o + 3
        b = a + n * n
        c = b + n
        for i in range(n):
            acc = opar[b + i] * u
            for j in range(n):
                acc += opar[a + i * n + j] * ostate[xo + j]
            opar[scr + i] = acc
        y = opar[o + 2] * u
        for i in range(n):
            x = opar[scr + i]
            ostate[xo + i] = x
            y += opar[c + i] * x
        if opar[o + 1] != 0.0:
            known += y - u
        u = y
        o = c + n
        xo += n
    return u, known
