"""The effect stages' compiled forms, inlined into the compiled model and observer steps
(:mod:`rtlift.blocks.compiled`, :mod:`rtlift.blocks.compiled_interaction`, :mod:`rtlift.observer.compiled`).

Input stages, each on its own arrays (the stage's ``kernel_arrays()``, not copies):

    delay            Cμ′(k) = Cμ(k − D), Cμ_env′(k) = Cμ_env(k − D)                 (:func:`_delayed`)
    actuator_fade    g(k) = f + (1 − f) exp(−E(k)/τ),  (Cμ′, Cμ_env′) = g (Cμ, Cμ_env)   (:func:`_faded`)
    onset_hold       Cμ_env′(k) = Cμ_env at the last burst onset, 0 while Cμ_env ≤ 0    (:func:`_held`)

in the model's order (:func:`_staged`): the delay before the fade, the hold before, between or
after them (its place a flag in the packed parameters, :data:`HOLD`; its state [u, Cμ(k−1)]
the last two floats of the stages' state array, :func:`bind_stage_states`).

Output stages, any number in any order, each in the state-space form every output stage states
(:meth:`rtlift.blocks.stage_base.OutputStage.statespace`, the paper's timing), on the stage's own state:

    x(k) = A x(k−1) + B u(k),   out(k) = C x(k) + D u(k),   u = the ΔCL the stage receives

(``zero_drift``, ``sensor_resonance``, ``periodic_disturbance``; :func:`_output_chain`). Their
parameters follow the model's in its packed array (:func:`with_outputs`) and their states are
views into one array with the fade's clock (:func:`bind_stage_states`), so the stages' own
``get_state``/``set_state`` and Python ``step`` see what the compiled step did, and the compiled
step takes no more arguments than it did without them (each array argument costs the numba
dispatcher ≈ 45 ns). The recurrences are the stages' own up to the order of
the additions, so the compiled and the Python chains agree to rounding.
"""

from __future__ import annotations

import math

import numpy as np

from rtlift.blocks.onset_hold import onset_value
from rtlift.core.jit import njit_cached

_onset_value = njit_cached(inline="always")(onset_value)
"""The hold's recurrence (:func:`rtlift.blocks.onset_hold.onset_value`), the Python step's own
code compiled: one statement of it for both steps."""


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


HYSTERESIS = 9
"""The hysteresis factor's parameters [on, m, g, w, λ, driver is "lift"] end this many floats
before the end of the packed array (then n_max, the stage count, the tail's length)."""
HOLD = HYSTERESIS + 1
"""The ``onset_hold`` stage's place sits this many floats before the end of the packed array
(:func:`with_outputs`, just before the hysteresis factor's parameters): 0 no hold, else one of
:data:`HOLD_FIRST`, :data:`HOLD_AFTER_DELAY`, :data:`HOLD_AFTER_FADE`."""
HOLD_FIRST, HOLD_AFTER_DELAY, HOLD_AFTER_FADE = 1.0, 2.0, 3.0
"""The hold before the delay, between the delay and the fade, after the fade."""


@njit_cached(inline="always")
def _held(cmu, env, sstate):
    """The ``onset_hold`` stage (:class:`rtlift.blocks.onset_hold.OnsetHold`): (Cμ, u), u the
    envelope at the last burst onset, 0 while Cμ_env ≤ 0; its state [u, Cμ(k−1)] the last two
    floats of ``sstate`` (:func:`bind_stage_states`)."""
    n = sstate.shape[0]
    u = _onset_value(sstate[n - 2], sstate[n - 1], cmu, env)
    sstate[n - 2] = u
    sstate[n - 1] = cmu
    return cmu, u


@njit_cached(inline="always")
def _staged(cmu, env, par, d_cmu, d_env, d_pos, fpar, sstate):
    """One sample through the model's input stages in its order: :func:`_delayed`, :func:`_faded`,
    and :func:`_held` where the flag ``par[−HOLD]`` puts it (0: no hold)."""
    where = par[par.shape[0] - HOLD]
    if where == HOLD_FIRST:
        cmu, env = _held(cmu, env, sstate)
    cmu, env = _delayed(cmu, env, d_cmu, d_env, d_pos)
    if where == HOLD_AFTER_DELAY:
        cmu, env = _held(cmu, env, sstate)
    cmu, env = _faded(cmu, env, fpar, sstate)
    if where == HOLD_AFTER_FADE:
        cmu, env = _held(cmu, env, sstate)
    return cmu, env


@njit_cached(inline="always")
def has_staged_inputs(par, d_cmu, fpar):
    """Whether the model has an input stage (a delay, a fade or the hold): the batches then run
    :func:`_staged_inputs` first."""
    return d_cmu.shape[0] > 0 or fpar[0] != 0.0 or par[par.shape[0] - HOLD] != 0.0


@njit_cached(inline="always")
def _staged_inputs(cmu, env, out_cmu, out_env, par, d_cmu, d_env, d_pos, fpar, fstate):
    """:func:`_staged` over whole arrays, into ``out_cmu``/``out_env`` (the batch's input
    stages; ``out_*`` not the inputs), leaving the rings, their position, the fade's clock and
    the hold's state as the same samples streamed would. A hold before the delay goes sample by
    sample through both; otherwise the delay is copies, not a loop
    through the ring: out(k) = ring((p + k) mod D) for k < D, in(k − D) after; the last D
    inputs go to their slots (p + k) mod D (through the ring sample by sample, each store made
    the next sample's position and ring be loaded again: ≈ 25 ns a sample on the benchmark
    record, more than the rest of the paper's structure)."""
    n = cmu.shape[0]
    n_delay = d_cmu.shape[0]
    where = par[par.shape[0] - HOLD]
    if where == HOLD_FIRST:
        for k in range(n):
            c, e = _held(cmu[k], env[k], fstate)
            out_cmu[k], out_env[k] = _delayed(c, e, d_cmu, d_env, d_pos)
    elif n_delay == 0:
        out_cmu[:] = cmu
        out_env[:] = env
    else:
        p = d_pos[0]
        head = min(n, n_delay)
        for k in range(head):
            i = (p + k) % n_delay
            out_cmu[k] = d_cmu[i]
            out_env[k] = d_env[i]
        out_cmu[head:] = cmu[:n - head]
        out_env[head:] = env[:n - head]
        for k in range(n - head, n):
            i = (p + k) % n_delay
            d_cmu[i] = cmu[k]
            d_env[i] = env[k]
        d_pos[0] = (p + n) % n_delay
    if where == HOLD_AFTER_DELAY:
        for k in range(n):
            out_cmu[k], out_env[k] = _held(out_cmu[k], out_env[k], fstate)
    if fpar[0] != 0.0:
        for k in range(n):
            out_cmu[k], out_env[k] = _faded(out_cmu[k], out_env[k], fpar, fstate)
    if where == HOLD_AFTER_FADE:
        for k in range(n):
            out_cmu[k], out_env[k] = _held(out_cmu[k], out_env[k], fstate)


STATE_OUTPUTS = 4
"""Where the output stages' states start in the stages' state array (after E and [h, s, p])."""


def with_outputs(par: np.ndarray, stages, memory: np.ndarray | None = None, hold: float = 0.0) -> np.ndarray:
    """The model's packed parameters ``par`` followed by the output stages': per stage n, counts
    toward the observer's known part (1.0; see :func:`_output_chain`), D, A (row-major), B, C;
    then n_max scratch floats, the ``onset_hold`` stage's place ``hold`` (:data:`HOLD`; 0: none),
    the hysteresis factor's parameters (:func:`_direction_factor`; ``memory`` = [m, g, w, λ,
    driver is "lift"], None: no factor), n_max, the stage count, and last this tail's length (so
    the step finds it from the end, whatever ``par`` holds before it)."""
    parts = []
    n_max = 0
    for st in stages:
        A, B, C, D = (np.asarray(v, dtype=float) for v in st.statespace())
        n = B.size
        n_max = max(n_max, n)
        parts.append(np.concatenate([[float(n), 1.0, float(D)], A.reshape(n * n), B, C]))
    n_max = max(n_max, 1)
    hyst = np.zeros(6) if memory is None else np.concatenate([[1.0], memory])
    tail = np.concatenate(parts + [np.zeros(n_max), [float(hold)], hyst, [float(n_max), float(len(stages))]])
    return np.concatenate([par, tail, [float(tail.size + 1)]])


def output_flags(par: np.ndarray, known: list[bool]) -> np.ndarray:
    """A copy of :func:`with_outputs`'s array whose per-stage flags say which stages' corrections
    count toward the observer's known part of the output (those it does not carry as states)."""
    out = par.copy()
    count = int(out[-2])
    if count != len(known):
        raise ValueError(f"{len(known)} flags for {count} output stages")
    o = out.size - int(out[-1])
    for flag in known:
        n = int(out[o])
        out[o + 1] = 1.0 if flag else 0.0
        o += 3 + n * n + 2 * n
    return out


def bind_stage_states(fade, memory, stages, hold=None) -> np.ndarray:
    """One array of the stages' states, [E of the ``actuator_fade``, [h, s, p] of the hysteresis
    factor (zeros without them), then each output stage's, then [u, Cμ(k−1)] of the ``onset_hold``
    stage ``hold`` (not there without it)], each one's own state array made a view into it (its
    current state copied in first), for the compiled step to advance in place."""
    sizes = [int(st.state_size) for st in stages]
    state = np.zeros(STATE_OUTPUTS + sum(sizes) + (2 if hold is not None else 0))
    if hold is not None:
        state[-2:] = hold.get_state()
        hold.adopt_state(state[-2:])
    if fade is not None:
        state[0] = fade.on_time
        fade.adopt_state(state[0:1])
    if memory is not None:
        state[1:4] = memory.get_state()
        memory.adopt_state(state[1:4])
    o = STATE_OUTPUTS
    for st, n in zip(stages, sizes, strict=True):
        view = state[o:o + n]
        view[:] = st.get_state()
        st.adopt_state(view)
        o += n
    return state


@njit_cached(inline="always")
def _direction_factor(q, env, par, sstate, offset):
    """The ``hysteresis`` factor (:class:`rtlift.blocks.wiener._DirectionMemory`) on the quasi-steady
    lift q (N(Cμ_env)·y or f(y)): returns q · g (1 + m h(k)), advancing [h, s, p] in ``sstate[1:4]``:

        p(k) = min(max(p(k−1), x − w/2), x + w/2),  s = (p − x)/w + 1/2      (w > 0)
        s = 1 if x < x(k−1), 0 if x > x(k−1), s(k−1) otherwise              (w = 0)
        h(k) = λ h(k−1) + (1 − λ) s(k),   x = Cμ_env (driver "cmu") or q + offset (driver "lift")

    (``offset`` the rest of the flow's slow lift: the interaction structure's burst slow term, 0
    in the paper's structure). Without the factor (its "on" 0) q is returned as it is."""
    o = par.shape[0] - HYSTERESIS
    if par[o] == 0.0:
        return q
    m, g, w, lam = par[o + 1], par[o + 2], par[o + 3], par[o + 4]
    x = q + offset if par[o + 5] != 0.0 else env
    if w > 0.0:
        half = 0.5 * w
        p = min(max(sstate[3], x - half), x + half)
        sstate[3] = p
        sstate[2] = (p - x) / w + 0.5
    else:
        if x < sstate[3]:
            sstate[2] = 1.0
        elif x > sstate[3]:
            sstate[2] = 0.0
        sstate[3] = x
    sstate[1] = (1.0 - lam) * sstate[2] + lam * sstate[1]
    return q * (g * (1.0 + m * sstate[1]))


@njit_cached(inline="always")
def direction_gain(par, sstate):
    """g (1 + m h) in force after this sample's step (1 without the factor): the observer's gain."""
    o = par.shape[0] - HYSTERESIS
    if par[o] == 0.0:
        return 1.0
    return par[o + 2] * (1.0 + par[o + 1] * sstate[1])


@njit_cached(inline="always")
def _output_chain(u, par, sstate):
    """ΔCL through the output stages packed at the end of ``par`` (:func:`with_outputs`),
    advancing their states in ``sstate[STATE_OUTPUTS:]`` (:func:`bind_stage_states`): (ΔCL after
    them, the sum of the flagged stages' corrections out − u)."""
    end = par.shape[0]
    count = int(par[end - 2])
    known = 0.0
    if count == 0:
        return u, known
    o = end - int(par[end - 1])
    scr = end - HOLD - int(par[end - 3])            # the scratch after the last stage
    xo = STATE_OUTPUTS
    for _ in range(count):
        n = int(par[o])
        a = o + 3
        b = a + n * n
        c = b + n
        for i in range(n):
            acc = par[b + i] * u
            for j in range(n):
                acc += par[a + i * n + j] * sstate[xo + j]
            par[scr + i] = acc
        y = par[o + 2] * u
        for i in range(n):
            x = par[scr + i]
            sstate[xo + i] = x
            y += par[c + i] * x
        if par[o + 1] != 0.0:
            known += y - u
        u = y
        o = c + n
        xo += n
    return u, known
