"""The live departure monitor: a running loop's residual against the model's fingerprint.

``rtlift identify`` stores the model's residual on its own campaign (the fingerprint,
:mod:`rtlift.residual.fingerprint`); its RMSE σ_fp on the records with a loop's kind of input
(:func:`fingerprint_scale`) is the scale every statistic here is measured in. The monitor watches
for what changes *while the loop runs*: a difference already there when it starts is the offline
diagnosis's to find (``rtlift diagnose``), and the observer's bias state absorbs it meanwhile.
Per sample the monitor takes the measured ΔCL z(k), the open-loop
model's ΔCL_m(k) (``est.model_dcl``) and the observer's innovation ν(k), and accumulates, in
blocks of ``block`` samples (1 s), the sums of

    e = z − ΔCL_m,   e²,   ΔCL_m,   ΔCL_m²,   e·ΔCL_m,   ν,   ν²,   ν(k)·ν(k−1)

(O(1) a sample, nothing allocated), and ν in a ring of the last ``window`` seconds. At the end of
each block it evaluates, over the last ``window`` blocks (``trend_window`` for the trend):

- ``bias``   |ē − ē₀| / σ_fp — the window's mean residual against the first judged window's ē₀ (a zero
  drift, a fade at a steady level). Against the run's own start, not the fingerprint's mean: that
  mean is each identification record's tare offset (on the independent plant −0.005 on its sine,
  +0.009 on its static sweep, with σ_fp 0.008), and a loop tares itself;
- ``gain``   |ĝ|, ĝ = Σ(e−ē)(m−m̄) / Σ(m−m̄)² — the residual's slope against the model's lift (a
  relative gain change of the actuation: a fade makes ĝ ≈ f − 1; the fingerprint's is ≈ 0, the
  model being fitted to its campaign); evaluated only when the window's std(ΔCL_m) ≥
  ``gain_excitation`` σ_fp, else 0. In a loop tracking steps these are the windows holding a step,
  where the model's dynamic misfit also shows: its threshold is the highest;
- ``level``  std(e − g(m_b)) / σ_fp — the residual's spread (added noise, an unmodelled mode);
- ``whiteness`` ρ₁(ν), the innovations' lag-1 autocorrelation (an unmodelled slow or resonant
  state colours them);
- ``line``   the largest ratio (dB) of the innovations' Hann periodogram in one bin to the
  median of the ±``line_half_width_hz`` around it, outside DC and the burst-rate harmonics
  (a narrow pickup);
- ``trend``  |slope of the block means of e| × the trend window / σ_fp — a slow drift;
- ``hold``   |ē_L − ē_ref| / σ_hold while the loop holds its operating point: a *hold* begins
  when the model's lift settles (its block means within ``hold_band`` σ_fp of each other over
  ``hold_reference`` blocks, ``hold_settle`` blocks after it last moved), ē_ref is the median of
  those blocks' e and m_ref of their m; while every later block's m stays within ``hold_band`` σ_fp
  of m_ref, ē_L (the mean of e over the last ``hold_current`` blocks) is compared with ē_ref. A
  block whose m leaves the band ends the hold (a reference step; the next one begins). σ_hold is
  the model's own block jitter on its quasi-static record, from the fingerprint
  (:func:`fingerprint_hold_scale`): how much 1-s block means of its residual move from one block
  to the next when nothing changes. A closed loop holds its operating point between reference
  steps, where a clean plant's residual stays put: what moves it then is the plant (a fade in a
  loop at first — the controller raises Cμ to hold the lift, so ē falls while m rises by as much —
  or a drifting zero). Measured against the hold's own start, not the run's first window, the
  model's misfit at other operating points does not enter it.

What no test judges: a block inside a transient — the run's start, a step of the operating point
commanded (:meth:`DepartureMonitor.set_steps`: ``rtlift control`` tells it its reference's steps)
or seen in the input (an open loop has no reference: an envelope jump from one sample to the next
whose lift-equivalent G·|ΔCμ| exceeds σ_fp, G the model's lift range over the envelope range it was
identified on, :func:`input_gain_of`; a moving envelope is not a step), the actuator switched off or
on in a closed loop (where the envelope's other jumps are the controller's feedback: the envelope
crossing σ_fp / G, G the model's, else the loop's own lift per Cμ over its last block — a device's
watchdog does it when the host's commands come late; size G·|ΔCμ|, else the model's lift range), a
swap of the model — is
left out of every window (all its sums zero), by one hold-off (:meth:`DepartureMonitor._transient`)
for the settling time :class:`Settle` derives from the model's own dynamics, prolonged (a commanded
step's) while its transient ends with the model's lift still moving from one block to the next
by more than ``hold_band`` σ_fp (a loop that rings after a step: on the loaded machine, commands
late by up to 0.6 s, the envelope swung for 3 s after a step, the residual's block mean up to
2.4 σ_fp); ``line`` waits until its ring holds no such sample, and a hold cannot span one. What the
model's misfit does at each operating point: a model file identified since issue 46 carries g(m),
its own mean residual against its lift (:mod:`rtlift.observer.monitor_print`), removed block by
block (e_b − g(m_b)) before ``bias``, ``level``, ``gain``, ``trend`` and the suspect's regression,
so a reference step does not move them by the misfit the model had at the new operating point all along.

A departure is raised when a statistic stays above its threshold for ``persist`` consecutive
evaluations; the same test is not raised again until it has been back under its threshold for
a whole window. The thresholds come, in this order, from a baseline run of the real loop
(``--monitor FILE``, written by ``--monitor calibrate FILE``), from the model file's own print (the
null distribution of every statistic on the model's own identification records,
:mod:`rtlift.observer.monitor_print`), else — an older model file, said in one line — the global
constants :data:`THRESHOLDS`, set from clean runs of our bench and the independent plant only
(``benchmarks/monitor_null.py --calibrate``: the largest value each statistic held for
``persist`` consecutive evaluations over the calibration seeds' clean streams, times
:data:`MARGIN`). The summary says which were in force (``thresholds_from``). A print's thresholds
hold for the inputs it was computed on: an input that shows the model more spread from the run's
first window on (:data:`INPUT_SPREAD`) is judged on the run's own scale, without ``whiteness``,
and the summary says so (``input``, :meth:`DepartureMonitor._input_against`).

The suspect named with a departure is what the diagnosis would try first (the diagnosis that
``--adapt`` runs decides). ``bias``, ``trend`` and ``hold`` see one thing — the residual's level
moved — and name it by one rule (:meth:`DepartureMonitor.level_suspect`), from the evidence rather
than the test's name: by the test's own signed shift, ``actuator_fade`` when the lift fell below
the model's, ``zero_drift`` when it rose (a fade cannot raise the lift), unless the residual's
block means follow the model's lift beyond doubt (the regression beside an offset and a trend in
time, t_b ≤ −:data:`FIT_T_STRONG`: the shift scales with the delivered actuation). In a closed
loop a fade's first seconds are too few blocks for that regression, and the controller raising Cμ
as the lift falls makes a fade and a falling zero look alike until later reference steps (the
fade's part scales with the lift, the drift's does not): the name is then the likelier cause on a
rig whose actuators heat as they run. (On the calibration draws 1 and 2, a fade's first ``bias`` 5 s after
its onset was named ``zero_drift`` by the earlier rule "the lift moved and the block means did not
follow"; until issue 46's third pass ``trend`` always named ``zero_drift``, and on the reporting
draws a fade's ``trend`` departure 9 s after its onset named it so beside the ``bias`` naming the
fade.) ``gain`` < 0 an ``actuator_fade``; ``line`` a ``periodic_disturbance`` at the peak's
frequency; ``level`` and ``whiteness`` an unmodelled ``resonance`` or noise. Each departure carries
the evidence it was named by (``evidence``: the regression's verdict and t_b, the signed shifts).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from rtlift.core.rate import FS_HZ
from rtlift.effects.actuator_fade import ActuatorFadeEffect
from rtlift.effects.periodic_disturbance import PeriodicDisturbanceEffect
from rtlift.effects.zero_drift import ZeroDriftEffect

TESTS = ("bias", "gain", "level", "whiteness", "line", "trend", "hold")
MARGIN = 1.25
"""Thresholds are the clean runs' largest persistent value times this margin."""

THRESHOLDS: Mapping[str, float] = {
    "bias": 0.8705, "gain": 0.2351, "level": 2.6901, "whiteness": 0.7771, "line": 25.5823, "trend": 1.5606,
    "hold": 4.2218,
}
"""Set by ``python -m benchmarks.monitor_null --calibrate`` from clean streams (module docstring);
the values and the runs they came from are in docs/INTERFACES.md ("Live departure monitor")."""

FIT_T_STRONG = 10.0
"""|t_b| of the block regression beyond which a rise of the residual that follows the model's lift
is named a fade (:meth:`DepartureMonitor.level_suspect`). Set on calibration draws 1 and 2
(``benchmarks.monitor_family --draws 1|2 --fault zero_drift:...``, a zero drift of ±4e-4 ΔCL/s
and of ±0.02 ΔCL with τ = 20 s, and a fade to 70 %): a zero drift's departures reached |t_b| 5.5
(a rising one's first ``bias`` read "proportional, t_b −3.8"), a fade's departures with a rising
trend late in the run −38 to −110."""

INPUT_SPREAD = 1.1
"""An input is outside the model's print (:meth:`DepartureMonitor._input_against`) when the residual's
spread in the run's first judged windows exceeds this × the largest on the model's own records. Set on
calibration draws 1, 2 and 4 (open loop, 60 s from the start, seeds 9000 + N + 10000 j, j = 0–2): on
``sine_k0125`` — the input the models were identified on — the first windows' largest spread reached
0.86–1.054 × the print's, on ``sine_k025`` 1.135–1.35, on ``random`` 1.55–2.05."""

N_SUMS = 9   # n, Σe, Σe², Σm, Σm², Σem, Σν, Σν², Σν(k)ν(k−1)


@dataclass(frozen=True)
class MonitorConfig:
    block_s: float = 1.0
    window_s: float = 6.0
    trend_window_s: float = 30.0
    persist: int = 2
    gain_excitation: float = 2.0
    line_half_width_hz: float = 2.0
    line_min_hz: float = 0.5
    burst_hz: float = 8.0
    burst_guard_hz: float = 0.4
    hold_band: float = 1.0
    hold_settle_s: float = 2.0
    hold_reference_s: float = 3.0
    hold_current_s: float = 2.0
    thresholds: Mapping[str, float] = field(default_factory=lambda: dict(THRESHOLDS))


START_RANGE = 20.0
"""Without the model's lift range (a model file from before the monitor's own print), the start is
taken as a step of 20 σ_fp: its transient's settling time is then 3 τ, the classic 95 % settle."""


@dataclass(frozen=True)
class Settle:
    """How long after a step of the operating point the residual still carries the step's own
    transient, from the model's own dynamics:

        T(Δ) = L / f_s + τ_slow · ln(max(Δ, σ_fp) / σ_fp)

    L the convolution kernel's length (the single-burst response: the model's memory of a burst),
    τ_slow the slowest time constant of its linear blocks (the Wiener part's and the high-pass's
    poles p: τ = −1 / (f_s ln|p|)), Δ the step's size in ΔCL: a transient of size Δ decaying at the
    model's slowest rate has fallen under the residual's own RMSE σ_fp after T. The start of a run
    (or a swap of the model) is a step of the model's lift range (``lift_range``: the largest
    |ΔCL_m| on its identification records; else :data:`START_RANGE` σ_fp)."""

    memory_s: float = 0.0
    tau_s: float = 0.0
    lift_range: float = math.nan

    def seconds(self, size: float, scale: float) -> float:
        return self.memory_s + self.tau_s * math.log(max(abs(size), scale) / scale)

    def samples(self, size: float, scale: float, fs_hz: float) -> int:
        return int(math.ceil(self.seconds(size, scale) * fs_hz))

    def start_size(self, scale: float) -> float:
        r = self.lift_range
        return r if r is not None and math.isfinite(r) and r > 0 else START_RANGE * scale

    @classmethod
    def of_model(cls, model: Any, scale: float, lift_range: float | None = None) -> Settle:
        fs = float(model.fs_hz)
        kernel = getattr(model.convolution, "kernel", None)
        memory = 0.0 if kernel is None else len(kernel) / fs
        poles = list(np.linalg.eigvals(np.atleast_2d(model.wiener.A)))
        sos = getattr(model.highpass, "sos", None)
        if sos is not None and np.size(sos):
            # each second-order section's poles: the roots of its denominator a₀ z² + a₁ z + a₂
            poles += [p for sec in np.atleast_2d(np.asarray(sos, dtype=float)) for p in np.roots(sec[3:])]
        taus = [-1.0 / (fs * math.log(abs(p))) for p in poles if 0.0 < abs(p) < 1.0]
        return cls(memory, max(taus, default=0.0), math.nan if lift_range is None else float(lift_range))


LOOP_LIKE = ("sine", "random")
"""Identification records whose input is a loop's kind (8 Hz bursts, a moving envelope)."""


def fingerprint_scale(fingerprint: Mapping[str, Any] | None) -> float:
    """σ_fp: the residual RMSE on the fingerprint's loop-like records (sines, random: the median
    if several), else the median over its dynamic records (not the static sweep); NaN without a
    fingerprint."""
    recs = (fingerprint or {}).get("records") or {}
    ok = {name: float(r["rmse"]) for name, r in recs.items()
          if isinstance(r, Mapping) and math.isfinite(float(r.get("rmse", math.nan)))}
    loop = [v for name, v in ok.items() if name.startswith(LOOP_LIKE)]
    vals = loop or [v for name, v in ok.items() if name != "static"]
    return float(np.median(vals)) if vals else math.nan


QUASI_STATIC = "static"
"""The identification record whose input holds still longest (the static sweep)."""


def fingerprint_hold_scale(fingerprint: Mapping[str, Any] | None, block_s: float = 1.0) -> float:
    """σ_hold: the standard deviation of a block mean's step from one ``block_s`` block to the next,
    of the model's residual on its quasi-static record (the static sweep; else the loop-like
    records' median), computed from the fingerprint's Welch PSD P(f) of that residual:

        σ_hold² = ½ ∫ P(f) sinc²(f T) 4 sin²(π f T) df,   T = ``block_s``

    (the variance of the difference of two adjacent T-means of a stationary series with one-sided
    PSD P, halved). Differences, not the block means' spread: a sweep's slow misfit moves the block
    means over tens of seconds, not from one block to the next. NaN without a usable PSD."""
    recs = (fingerprint or {}).get("records") or {}

    def one(r: Any) -> float:
        psd = r.get("psd") if isinstance(r, Mapping) else None
        if not psd:
            return math.nan
        f = np.asarray(psd["f_hz"], dtype=float)
        p = 10.0 ** np.asarray(psd["log10"], dtype=float)
        h2 = np.sinc(f * block_s) ** 2 * 4.0 * np.sin(np.pi * f * block_s) ** 2
        g = p * h2
        var = float(np.sum(0.5 * (g[1:] + g[:-1]) * np.diff(f)))
        return math.sqrt(0.5 * var) if var > 0 else math.nan

    if QUASI_STATIC in recs and math.isfinite(one(recs[QUASI_STATIC])):
        return one(recs[QUASI_STATIC])
    vals = [v for name, r in recs.items() if name.startswith(LOOP_LIKE) and math.isfinite(v := one(r))]
    return float(np.median(vals)) if vals else math.nan


class DepartureMonitor:
    """Sliding-window departure tests of a running observer's residual (module docstring).

    :meth:`step` once per sample (the hot path: float arithmetic and array stores only);
    ``departures`` collects ``{t_s, test, statistic, threshold, suspect}`` dicts, and
    ``on_departure`` (if set) is called with each as it is raised.
    """

    def __init__(self, scale: float, fs_hz: float = FS_HZ, config: MonitorConfig | None = None,
                 hold_scale: float = math.nan, settle: Settle | None = None,
                 operating_point: Mapping[str, Any] | None = None, input_gain: float = math.nan) -> None:
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"monitor scale (the fingerprint's residual RMSE) must be positive, got {scale!r}")
        self.scale = float(scale)
        self.hold_scale = float(hold_scale) if math.isfinite(hold_scale) and hold_scale > 0 else math.nan
        """σ_hold (:func:`fingerprint_hold_scale`); NaN turns the ``hold`` test off."""
        self.fs_hz = float(fs_hz)
        self.config = cfg = config or MonitorConfig()
        self.block = max(1, int(round(cfg.block_s * fs_hz)))
        self.window_blocks = max(2, int(round(cfg.window_s / cfg.block_s)))
        self.trend_blocks = max(self.window_blocks, int(round(cfg.trend_window_s / cfg.block_s)))
        self.thresholds = {k: float(cfg.thresholds.get(k, math.inf)) for k in TESTS}
        self.threshold_source = "the global constants (rtlift.observer.monitor.THRESHOLDS)"
        self.settle = settle or Settle()
        """How long a window holding the start or a step of the operating point is kept out of every test."""
        op = operating_point or {}
        self._op_m = np.asarray(op.get("m", ()), dtype=float)
        self._op_e = np.asarray(op.get("e", ()), dtype=float)
        """g(m): the model's own misfit against its lift, piecewise linear (:func:`operating_point_misfit`);
        empty: none removed."""
        self._steps = np.zeros(0)
        self._step_sizes = np.zeros(0)
        self.input_gain = float(input_gain) if math.isfinite(input_gain) and input_gain > 0 else math.nan
        """G (ΔCL per Cμ): the model's lift range over the envelope range it was identified on; an
        envelope jump ΔCμ from one sample to the next with G·|ΔCμ| > σ_fp is a step of the operating
        point (:meth:`step`). NaN: the input is not watched (a model file without its print)."""
        self.input_jump = self.scale / self.input_gain if math.isfinite(self.input_gain) else math.inf
        self.input_steps = 0
        """Steps of the operating point seen in the input (the envelope) so far."""
        self.switches = 0
        """Input steps that switched the actuator off or on (counted in ``input_steps``)."""
        self._told = False
        self._off_env = self.input_jump if math.isfinite(self.input_gain) else 0.0
        """The envelope at or below which the actuator is off (a closed loop, :meth:`step`): its
        lift-equivalent within σ_fp of none, σ_fp / G — without G, G the loop's own lift per Cμ over
        its last block (0 until one: exactly off)."""
        self._switch_size = self.settle.start_size(self.scale)
        """A switch of the actuator's size in ΔCL when G is not known: the model's lift range, as the start."""
        self.print_inputs: list[str] = []
        """The identification records the model's print was computed on (the inputs its thresholds are for)."""
        self.level_null = math.inf
        """The largest ``level`` (held ``persist`` evaluations) on the model's own identification records
        (its print's ``persistent_max``); inf: not known, the input is never judged outside the print."""
        if math.isnan(self.hold_scale):
            self.thresholds["hold"] = math.inf
        self._hold_blocks = tuple(max(1, int(round(x / cfg.block_s)))
                                  for x in (cfg.hold_settle_s, cfg.hold_reference_s, cfg.hold_current_s))
        self._blocks = np.zeros((self.trend_blocks, N_SUMS))
        self._ring = np.zeros(self.window_blocks * self.block)
        n = self._ring.size
        self._hann = np.hanning(n)
        f = np.fft.rfftfreq(n, 1.0 / fs_hz)
        self._freqs = f
        harm = np.abs(f / cfg.burst_hz - np.round(f / cfg.burst_hz)) * cfg.burst_hz
        self._line_ok = (f >= cfg.line_min_hz) & (harm > cfg.burst_guard_hz) & (f < fs_hz / 2 - cfg.line_half_width_hz)
        self._line_half = max(2, int(round(cfg.line_half_width_hz * n / fs_hz)))
        self.on_departure = None
        self.departures: list[dict[str, Any]] = []
        self.evaluations = 0
        self.last: dict[str, float] = {}
        self.history: list[dict[str, float]] | None = None
        """Set to a list to keep every evaluation's statistics (calibration from clean runs)."""
        self.reset()

    @classmethod
    def for_model(cls, model: Any, config: MonitorConfig | None = None) -> DepartureMonitor:
        scale = fingerprint_scale(getattr(model, "fingerprint", None))
        if not math.isfinite(scale):
            raise ValueError("the model file has no residual fingerprint (identify it with rtlift identify)")
        cfg = config or MonitorConfig()
        own = (model.fingerprint or {}).get("monitor") or {}
        thresholds = own.get("thresholds")
        if thresholds:
            cfg = replace(cfg, thresholds={**THRESHOLDS, **{k: float(v) for k, v in thresholds.items()
                                                            if v is not None}})
        mon = cls(scale, model.fs_hz, cfg, fingerprint_hold_scale(model.fingerprint, cfg.block_s),
                  Settle.of_model(model, scale, own.get("lift_range")), own.get("operating_point"),
                  input_gain_of(model, own.get("lift_range")))
        if thresholds:
            kept = [k for k in TESTS if thresholds.get(k) is None]
            mon.threshold_source = (f"the model's own identification records ({own.get('source', 'fingerprint')})"
                                    + (f"; {', '.join(kept)}: the global constants (never evaluated there)"
                                       if kept else ""))
            mon.level_null = float((own.get("persistent_max") or {}).get("level") or math.inf)
            mon.print_inputs = sorted(n for n in (model.fingerprint.get("records") or {})
                                      if n.startswith(LOOP_LIKE) or n == QUASI_STATIC)
        return mon

    def use_thresholds(self, thresholds: Mapping[str, float], source: str) -> None:
        """Thresholds from elsewhere (``--monitor FILE``: a baseline run); tests not named keep theirs."""
        for k, v in thresholds.items():
            if k in self.thresholds and v is not None:
                self.thresholds[k] = float(v)
        if math.isnan(self.hold_scale):
            self.thresholds["hold"] = math.inf
        self.threshold_source = source
        self.level_null = math.inf          # a baseline run of the real loop: its input's own null

    def set_steps(self, samples: Any, sizes: Any) -> None:
        """The samples (the monitor's count) at which the operating point is commanded to step
        (a controller's reference), and the steps' sizes (ΔCL): each window holding a step's
        settling time (:class:`Settle`) is kept out of the tests."""
        order = np.argsort(np.asarray(samples, dtype=float), kind="stable")
        self._steps = np.asarray(samples, dtype=float)[order]
        self._step_sizes = np.abs(np.asarray(sizes, dtype=float))[order]
        self._told = bool(self._steps.size)
        self._next_step = int(np.searchsorted(self._steps, self._sample))

    def reset(self) -> None:
        """Windows, runs and the sample count cleared (a new run)."""
        self._sample = 0
        self.input_scale = 1.0
        """σ_run / σ_fp (:meth:`_input_against`): 1 unless the input is outside the model's print."""
        self.outside_print_s: float | None = None
        self._prev_env = math.nan
        self._jump_at = -1              # the sample of the last input step seen in this block
        self._jump_size = 0.0           # the largest one's lift-equivalent size (ΔCL)
        self._switched = False          # one of them switched the actuator off or on
        self._env_sum, self._env_n = 0.0, 0     # the envelope's sum and count in this block
        self.clear_windows()

    def clear_windows(self) -> None:
        """Forget the windows (the model was swapped: its residual starts afresh); the sample
        count and the departures so far are kept."""
        self._blocks[:] = 0.0
        self._acc = [0.0] * N_SUMS
        self._in_block = 0
        self._nb = 0           # blocks completed
        self._pos = 0          # next write position in the ring
        self._since = 0        # samples since the windows were cleared
        self._ring[:] = 0.0
        self._prev_nu = math.nan
        self._bias_ref: float | None = None
        self._bias_shift = 0.0
        self._trend_slope = 0.0         # the trend's signed slope of the block means (ΔCL/s)
        self._fit = ("none", 0.0)
        self._off_on = None             # the residual's shift in the window's unactuated / actuated blocks
        self._held: list[str] = []
        self._gain_sign = 0.0
        self._run = dict.fromkeys(TESTS, 0)
        self._quiet = dict.fromkeys(TESTS, self.window_blocks)
        self._active = dict.fromkeys(TESTS, False)
        self._hold_start = 0            # block count at which the current hold began
        self._hold_ref: tuple[float, float] | None = None
        self._hold = 0.0                # the hold statistic after the last block (signed, σ_hold)
        self._ok = np.zeros(self.trend_blocks, dtype=bool)   # a block outside every transient
        self._prev_m = math.inf         # the last block's mean model lift
        # the start (or the swap) is a transient of the model's whole lift range
        self._quiet_from = self._sample + self.settle.samples(self.settle.start_size(self.scale), self.scale,
                                                              self.fs_hz)
        self._next_step = int(np.searchsorted(self._steps, self._sample))

    # -- the hot path -------------------------------------------------------------------
    def step(self, dcl: float | None, model_dcl: float, innovation: float, envelope: float = math.nan) -> None:
        """One sample: measured ΔCL (``None``/NaN: no measurement), the open-loop model's ΔCL,
        the observer's innovation (NaN when there was no update) and the input's envelope Cμ
        (NaN: not given). An envelope jump from the last sample with G·|ΔCμ| > σ_fp (G =
        ``input_gain``) is a step of the operating point: its transient is held off as a
        commanded step's is (:meth:`_transient`) — unless the monitor was told a reference's steps
        (:meth:`set_steps`): in a closed loop the operating point moves when the reference does,
        and the envelope's own jumps are the controller's answer to the estimate (its feedback),
        not steps of it; there only the actuator switched off or on is a step (the envelope
        crossing σ_fp / G, where its lift is within σ_fp of none: a device's watchdog ramps it to 0
        when the host's commands come 500 ms late, and no controller tracking a lift answers its
        estimate's noise so)."""
        if envelope == envelope:
            p = self._prev_env
            d = envelope - p
            self._env_sum += envelope
            self._env_n += 1
            if self._told:
                off = self._off_env
                if (envelope <= off) is not (p <= off) and p == p:
                    # the actuator switched off or on: a step of the operating point, not feedback
                    self._switched = True
                    self._jump_at = self._sample
                    d = abs(d) * self.input_gain if self.input_gain == self.input_gain else self._switch_size
                    if d > self._jump_size:
                        self._jump_size = d
            elif d > self.input_jump or d < -self.input_jump:
                self._jump_at = self._sample
                d = abs(d) * self.input_gain
                if d > self._jump_size:
                    self._jump_size = d
            self._prev_env = envelope
        a = self._acc
        if dcl is not None and dcl == dcl and model_dcl == model_dcl:
            e = dcl - model_dcl
            a[0] += 1.0
            a[1] += e
            a[2] += e * e
            a[3] += model_dcl
            a[4] += model_dcl * model_dcl
            a[5] += e * model_dcl
        nu = innovation if innovation == innovation else 0.0
        a[6] += nu
        a[7] += nu * nu
        p = self._prev_nu
        if p == p:
            a[8] += nu * p
        self._prev_nu = nu
        ring = self._ring
        ring[self._pos] = nu
        self._pos += 1
        if self._pos == ring.size:
            self._pos = 0
        self._sample += 1
        self._since += 1
        self._in_block += 1
        if self._in_block == self.block:
            self._end_block()

    # -- once a block -------------------------------------------------------------------
    def _end_block(self) -> None:
        row = self._blocks[self._nb % self.trend_blocks]
        row[:] = self._acc
        steps, k = self._steps, self._next_step
        while k < steps.size and steps[k] < self._sample:      # a step commanded within this block
            self._transient(int(steps[k]), float(self._step_sizes[k]))
            k += 1
        self._next_step = k
        if self._jump_at >= 0:                                 # a step seen in the input within it
            self._transient(self._jump_at, self._jump_size)
            self.input_steps += 1
            self.switches += self._switched
            self._jump_at, self._jump_size, self._switched = -1, 0.0, False
        if self._env_n and row[0] > 0 and self.input_gain != self.input_gain:
            u, m = self._env_sum / self._env_n, row[3] / row[0]
            if u > 0.0 and m > 0.0:     # without G, the loop's own lift per Cμ over this block
                self._off_env = self.scale * u / m
        self._env_sum, self._env_n = 0.0, 0
        start = self._sample - self.block
        if row[0] > 0:
            m = row[3] / row[0]
            moved = abs(m - self._prev_m) if math.isfinite(self._prev_m) else 0.0
            if steps.size and start < self._quiet_from and moved > self.config.hold_band * self.scale:
                # the loop's lift still moving at a commanded step's transient's end (a loop that
                # rings, commands arriving late): the transient lasts until it has settled
                self._transient(self._sample, moved)
            self._prev_m = m
        self._ok[self._nb % self.trend_blocks] = start >= self._quiet_from
        self._acc = [0.0] * N_SUMS
        self._in_block = 0
        self._nb += 1
        self._update_hold(row)
        if self._nb >= self.window_blocks:
            self._evaluate()

    def _input_against(self, level: float, held: bool) -> float:
        """The scale factor σ_run / σ_fp of the ``bias``, ``level`` and ``trend`` tests, decided on the
        run's first ``window`` evaluations (those of them judged; later ones, which may hold a change,
        never decide): when the residual's spread there (``level``, in
        σ_fp) exceeds :data:`INPUT_SPREAD` × the largest the model showed on its own identification
        records (``level_null``, its print's persistent maximum), the input being observed is one the print
        has no null for (a broadband envelope on a model identified on sines and sweeps shows it
        more misfit from the first window on, before anything changed). From then on those tests
        are judged on the run's own scale, σ_run = the largest such spread × σ_fp (a change from
        the run's start, as ``bias`` is), ``whiteness`` is not judged, and the summary says so
        (thresholds from other inputs: ``--monitor calibrate`` gives them for this one). Returns
        the factor in force for this evaluation."""
        if held or level <= 0.0 or self.evaluations >= self.window_blocks:
            return self.input_scale
        if level > INPUT_SPREAD * self.level_null and level > self.input_scale:
            self.input_scale = level
            if self.outside_print_s is None:
                self.outside_print_s = self._sample / self.fs_hz
        return self.input_scale

    def _transient(self, sample: int, size: float) -> None:
        """The one hold-off: a step of the operating point of ``size`` ΔCL at ``sample`` (commanded
        by a reference, seen in the input, or a ringing loop's move) keeps every block starting
        within its settling time (:class:`Settle`) out of every test."""
        self._quiet_from = max(self._quiet_from, sample + self.settle.samples(size, self.scale, self.fs_hz))

    def _update_hold(self, row: np.ndarray) -> None:
        """The ``hold`` test's state after a block (module docstring): begin, keep or end a hold,
        and its statistic (0 outside a hold's comparison)."""
        self._hold = 0.0
        if math.isnan(self.hold_scale):
            return
        settle, ref_n, cur_n = self._hold_blocks
        band = self.config.hold_band * self.scale
        if row[0] <= 0 or not self._ok[(self._nb - 1) % self.trend_blocks]:
            # no measurement, or a transient (the start, a step, a swap): a hold cannot span it
            self._hold_start, self._hold_ref = self._nb, None
            return
        m = row[3] / row[0]
        ref = self._hold_ref
        if ref is not None and abs(m - ref[1]) > band:
            self._hold_start, self._hold_ref = self._nb - 1, None
            return
        if ref is None:
            if self._nb - self._hold_start >= settle + ref_n:
                w = self._window_sums(ref_n)
                ms = w[:, 3] / w[:, 0]
                if float(np.ptp(ms)) <= 0.5 * band:
                    self._hold_ref = (float(np.median(w[:, 1] / w[:, 0])), float(np.median(ms)))
                else:                                   # not settled yet: try the next blocks
                    self._hold_start = self._nb - settle - ref_n + 1
            return
        w = self._window_sums(cur_n)
        self._hold = (float(w[:, 1].sum() / w[:, 0].sum()) - ref[0]) / self.hold_scale

    def _window_sums(self, blocks: int, quiet: bool = True) -> np.ndarray:
        """The last ``blocks`` blocks' sums, newest first (a copy); with ``quiet`` a block inside a
        transient (the start, a step's settling time, a swap) is all zeros: no test sees it."""
        nb = min(self._nb, self.trend_blocks)
        idx = [(self._nb - 1 - i) % self.trend_blocks for i in range(min(blocks, nb))]
        w = self._blocks[idx]
        if quiet:
            w[~self._ok[idx]] = 0.0
        return w

    def _misfit_of(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per block of ``w`` with samples: its mean residual less the model's own misfit at its
        operating point, e_b − g(m_b) (:func:`operating_point_misfit`), and m_b."""
        e, m, g = self._blocks_of(w)
        return e - g, m

    def _blocks_of(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per block of ``w`` with samples: e_b, m_b and g(m_b) (0 without an operating-point misfit)."""
        ok = w[:, 0] > 0
        n = w[ok, 0]
        e, m = w[ok, 1] / n, w[ok, 3] / n
        g = np.interp(m, self._op_m, self._op_e) if self._op_m.size else np.zeros_like(m)
        return e, m, g

    def statistics(self) -> dict[str, float]:
        """The six statistics over the current windows (module docstring)."""
        cfg, sc = self.config, self.scale
        w = self._window_sums(self.window_blocks)
        n, se, se2, sm, sm2, sem, sn, sn2, snn = w.sum(axis=0)
        out = dict.fromkeys(TESTS, 0.0)
        self._fit = ("none", 0.0)
        self._off_on: tuple[float, float | None] | None = None
        self._held = []
        quiet = int(np.count_nonzero(w[:, 0] > 0))
        if n < 0.5 * self.window_blocks * self.block and quiet < w.shape[0]:
            self._held += ["bias", "level", "gain"]        # a transient left too little of the window
        if (quiet < 0.5 * self.window_blocks and quiet < w.shape[0]) or self.outside_print_s is not None:
            self._held.append("whiteness")      # a transient, or an input its print has no null for
        if n >= 0.5 * self.window_blocks * self.block:
            em, mm = se / n, sm / n
            var_m = max(sm2 / n - mm * mm, 0.0)
            raw, mb, gb = self._blocks_of(w)
            eb = raw - gb
            nb = w[w[:, 0] > 0, 0]
            ec = float(nb @ eb / nb.sum())        # the window's mean residual, g(m) removed
            # Σ(e − g_b)² = Σe² − 2 g_b Σe + n_b g_b², block by block
            var_e = max((se2 - 2.0 * float(gb @ (nb * raw)) + float(nb @ gb ** 2)) / n - ec * ec, 0.0)
            if self._bias_ref is None:
                self._bias_ref = ec
            self._bias_shift = ec - self._bias_ref
            su = sc * self._input_against(math.sqrt(var_e) / sc, "level" in self._held)
            off = np.abs(mb) < sc          # the actuator off: the model's lift within σ_fp of none
            if off.any():
                on = ~off
                self._off_on = (float(nb[off] @ eb[off] / nb[off].sum()) - self._bias_ref,
                                float(nb[on] @ eb[on] / nb[on].sum()) - self._bias_ref if on.any() else None)
            out["bias"] = abs(self._bias_shift) / su
            out["level"] = math.sqrt(var_e) / su
            if math.sqrt(var_m) >= cfg.gain_excitation * sc:
                g = (sem / n - em * mm) / var_m
                if self._op_m.size:             # less the slope g(m) itself has over the window's blocks
                    gm = np.interp(mb, self._op_m, self._op_e)
                    dm = mb - nb @ mb / nb.sum()
                    if dm @ (nb * dm) > 0:
                        g -= float((nb * dm) @ gm / (dm @ (nb * dm)))
                out["gain"] = abs(g)
                self._gain_sign = g
            self._fit = self._block_slope(self._window_sums(self.trend_blocks))
        m = quiet * self.block
        if quiet >= 0.5 * self.window_blocks:
            mean_nu = sn / m
            var_nu = sn2 / m - mean_nu * mean_nu
            if var_nu > 0:
                out["whiteness"] = (snn / m - mean_nu * mean_nu) / var_nu
                if self._since >= self._ring.size and self._sample - self._quiet_from >= self._ring.size:
                    out["line"] = self._line()
                elif self._since >= self._ring.size:
                    self._held.append("line")           # its ring holds a transient
        t = self._window_sums(self.trend_blocks)
        if len(t) >= self.trend_blocks:
            ok = t[:, 0] > 0
            if ok.sum() >= 0.5 * len(t):
                means, _ = self._misfit_of(t)
                x = -np.arange(len(t), dtype=float)[ok] * self.config.block_s
                xc = x - x.mean()
                slope = float(xc @ (means - means.mean()) / (xc @ xc))
                self._trend_slope = slope
                out["trend"] = abs(slope) * self.config.trend_window_s / (sc * self.input_scale)
        out["hold"] = abs(self._hold)
        return out

    def _block_slope(self, w: np.ndarray) -> tuple[str, float]:
        """Regression of the block means of e on those of ΔCL_m over the trend window (up to 30
        blocks), beside an offset and a trend in time (e_i = a + c t_i + b m_i: a drift is the
        offset and trend, a gain change the part that follows the model's lift — in a loop the
        residual of a fade jumps with each step of the lift, a drift's does not): ("proportional",
        t_b) when |t_b| ≥ 3 (beyond Student's 97.5 % point for ≥ 5 degrees of freedom),
        ("offset", t_b) when the model's lift moved enough for b to be seen (its block means' std
        ≥ σ_fp) and it was not, ("unknown", t_b) otherwise. ``w`` holds the blocks newest first."""
        ok = w[:, 0] > 0
        if ok.sum() < 8:
            return ("unknown", 0.0)
        e, m = self._misfit_of(w)
        t = -np.arange(len(w), dtype=float)[ok]
        X = np.column_stack([np.ones_like(t), t, m])
        coef, _, rank, _ = np.linalg.lstsq(X, e, rcond=None)
        dof = e.size - 3
        if rank < 3 or dof < 1:
            return ("unknown", 0.0)
        res = e - X @ coef
        s2 = float(res @ res) / dof
        cov = s2 * np.linalg.pinv(X.T @ X)
        se = math.sqrt(max(cov[2, 2], 0.0))
        tb = float(coef[2]) / se if se > 0 else math.copysign(math.inf, float(coef[2]))
        if abs(tb) >= 3.0:
            return ("proportional", tb)
        return ("offset", tb) if float(np.std(m)) >= self.scale else ("unknown", tb)

    def _line(self) -> float:
        x = np.roll(self._ring, -self._pos)
        x = (x - x.mean()) * self._hann
        p = np.abs(np.fft.rfft(x)) ** 2
        h = self._line_half
        cand = np.flatnonzero(self._line_ok)
        if cand.size == 0:
            return 0.0
        k = int(cand[np.argmax(p[cand])])
        lo, hi = max(0, k - h), min(p.size, k + h + 1)
        med = float(np.median(p[lo:hi]))
        self._line_hz = float(self._freqs[k])
        return 10.0 * math.log10(p[k] / med) if med > 0 else 0.0

    def _evaluate(self) -> None:
        stats = self.statistics()
        self.last = stats
        self.evaluations += 1
        if self.history is not None:
            self.history.append(stats)
        self.judge(stats, self._sample / self.fs_hz, self._held)

    def judge(self, stats: Mapping[str, float], t_s: float, held: Any = ()) -> None:
        """One evaluation's statistics against the thresholds: a departure when one stays above its
        threshold for ``persist`` evaluations (not raised again until back under for a window).
        A test ``held`` (its window held a transient) counts neither way."""
        for test in TESTS:
            if test in held:
                continue
            v, thr = stats[test], self.thresholds[test]
            if v > thr:
                self._run[test] += 1
                self._quiet[test] = 0
                if self._run[test] >= self.config.persist and not self._active[test]:
                    self._active[test] = True
                    self._raise(t_s, test, v, thr)
            else:
                self._run[test] = 0
                self._quiet[test] += 1
                if self._quiet[test] >= self.window_blocks:
                    self._active[test] = False

    def level_suspect(self, change: float) -> str:
        """The one naming of a shift of the residual's level, whichever test saw it (``bias``,
        ``trend``, ``hold``): the evidence, not the statistic's name. ``change`` is the test's own
        signed shift (ΔCL, or ΔCL/s for the trend; e = z − ΔCL_m):

        - the lift fell below the model's (``change`` < 0): ``actuator_fade``;
        - it rose: ``zero_drift`` (a fade cannot raise the lift) — unless the residual follows
          the delivered actuation beyond doubt: the block regression over the trend window
          (:meth:`_block_slope`) finds its part proportional to the model's lift with
          t_b ≤ −:data:`FIT_T_STRONG` (a fade's residual steps with each reference step, so the
          sign of its 30-s trend follows the reference's last steps, not the fade).

        A fall is a ``zero_drift`` after all when the window shows it where nothing actuated: a
        fade lowers the lift only in proportion to the actuation, so in the window's blocks with the
        actuator off (the model's lift within σ_fp of none) its residual stays where it was, while
        a falling zero lowers it there as much as anywhere. With such blocks in the window, the
        fall is named ``zero_drift`` when their residual has moved from the run's start (the
        ``bias`` reference) by more than half what the actuated blocks' has (the midpoint between
        the two causes), or when no block was actuated at all.

        What this cannot tell: a zero *falling* while a loop holds its operating point with the
        actuator on throughout. The loop raises Cμ to hold the lift either way, so the residual
        falls as the model's lift rises for both, and a drift's not scaling with the actuation
        shows only across later reference steps; it is named ``actuator_fade`` (the likelier cause
        on a rig whose actuators heat as they run) and the diagnosis ``--adapt`` runs decides."""
        kind, t = self._fit
        if change < 0:
            off = self._off_on
            if off is not None and (off[1] is None or (off[1] < 0 and off[0] < 0.5 * off[1])):
                return ZeroDriftEffect.name
            return ActuatorFadeEffect.name
        if kind == "proportional" and t <= -FIT_T_STRONG:
            return ActuatorFadeEffect.name
        return ZeroDriftEffect.name

    def suspect(self, test: str) -> str:
        """The effect a departure of ``test`` points at (its name, :mod:`rtlift.effects`), or what
        no effect models: ``gain_increase`` (the gain rose; a fade only lowers it) and
        ``resonance or added noise``. ``bias``, ``trend`` and ``hold`` are one naming
        (:meth:`level_suspect`) of their own signed shift."""
        if test in ("bias", "trend", "hold"):
            return self.level_suspect({"bias": self._bias_shift, "trend": self._trend_slope,
                                       "hold": self._hold}[test])
        if test == "gain":
            return ActuatorFadeEffect.name if self._gain_sign < 0 else "gain_increase"
        if test == "line":
            return f"{PeriodicDisturbanceEffect.name} at {getattr(self, '_line_hz', math.nan):.2f} Hz"
        return "resonance or added noise"

    def _raise(self, t_s: float, test: str, value: float, threshold: float) -> None:
        kind, tb = self._fit
        d = {"t_s": round(t_s, 6), "test": test, "statistic": float(value), "threshold": threshold,
             "suspect": self.suspect(test), "sample": self._sample,
             "evidence": {"fit": kind, "t_b": round(float(tb), 3) if math.isfinite(tb) else None,
                          "bias_shift": float(self._bias_shift),
                          "trend_slope": float(self._trend_slope), "hold": float(self._hold),
                          "off_on_shift": self._off_on}}
        self.departures.append(d)
        if self.on_departure is not None:
            self.on_departure(d)

    def input_summary(self) -> dict[str, Any]:
        """Whether the observed input was one the model's print has a null for (:meth:`_input_against`),
        in a plain sentence (``note``)."""
        out: dict[str, Any] = {"print_inputs": self.print_inputs, "outside_print_s": self.outside_print_s,
                               "scale_factor": self.input_scale,
                               "level_null": self.level_null if math.isfinite(self.level_null) else None}
        if self.outside_print_s is not None:
            out["note"] = (f"the input showed the model a residual spread {self.input_scale:.2f} sigma_fp from the "
                           f"run's start, beyond its largest on the records its thresholds came from "
                           f"({', '.join(self.print_inputs) or 'its identification records'}: "
                           f"{self.level_null:.2f}): bias, level and trend were judged on the run's own scale "
                           f"(changes from its start), whiteness not at all; thresholds from this input need a "
                           f"clean baseline of it (--monitor calibrate OUT.json, then --monitor OUT.json) long "
                           f"enough to hold its own spread: on a random envelope 10 minutes were not")
        return out

    def summary(self) -> dict[str, Any]:
        def finite(v: float) -> float | None:
            return float(v) if math.isfinite(v) else None

        return {"scale": self.scale, "hold_scale": finite(self.hold_scale), "evaluations": self.evaluations,
                "thresholds": {k: finite(v) for k, v in self.thresholds.items()},
                "thresholds_from": self.threshold_source,
                "settle": {"memory_s": self.settle.memory_s, "tau_s": self.settle.tau_s,
                           "start_s": self.settle.seconds(self.settle.start_size(self.scale), self.scale),
                           "steps": int(self._steps.size), "input_steps": self.input_steps,
                           "actuator_switches": self.switches,
                           "input_jump_cmu": finite(self.input_jump)},
                "operating_point_misfit": bool(self._op_m.size),
                "input": self.input_summary(),
                "last": {k: float(v) for k, v in self.last.items()}}


def input_gain_of(model: Any, lift_range: float | None) -> float:
    """G = the model's lift range (its largest |ΔCL_m| on its identification records, from its
    print) over the largest envelope Cμ it was identified on (``provenance.domain``): ΔCL per Cμ,
    the lift-equivalent of an input jump. NaN when either is missing (an older model file)."""
    dom = (getattr(model, "provenance", None) or {}).get("domain") or {}
    top = float(dom.get("cmu_envelope_max") or math.nan)
    r = math.nan if lift_range is None else float(lift_range)
    return r / top if math.isfinite(r) and math.isfinite(top) and top > 0 and r > 0 else math.nan


def persistent_max(values: Any, persist: int) -> float:
    """The largest value a statistic held for ``persist`` consecutive evaluations (0 if fewer)."""
    v = np.asarray(values, dtype=float)
    if v.size < persist:
        return 0.0
    return float(np.lib.stride_tricks.sliding_window_view(v, persist).min(axis=1).max())


def monitor_arrays(monitor: DepartureMonitor, dcl: np.ndarray, model_dcl: np.ndarray,
                   innovation: np.ndarray, envelope: np.ndarray | None = None) -> DepartureMonitor:
    """Feed whole arrays (an estimate file, a replay; ``envelope`` Cμ, if given: the input
    watched for steps) sample by sample through ``monitor``."""
    step = monitor.step
    env = np.full(len(dcl), math.nan) if envelope is None else np.asarray(envelope, dtype=float)
    for z, m, v, u in zip(dcl.tolist(), model_dcl.tolist(), innovation.tolist(), env.tolist(), strict=True):
        step(z, m, v, u)
    return monitor
