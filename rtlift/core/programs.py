"""Experiment programs: what the actuator does, as a schedule (INTERFACES.md, "Program files").

A program is a table of rows ``(t, envelope_v, burst_period_ms)``: from time ``t`` (s, from
the program's start) on, bursts every ``burst_period_ms`` at amplitude ``envelope_v`` (V);
``envelope_v`` 0 = off, ``burst_period_ms`` 0 = keep the current period. The last row
ends the program (its envelope must be 0). The tare (actuator off) is not part of a program:
whoever runs it puts the tare in front.

Burst onsets (:meth:`Program.onsets`), as a protocol-version-2 firmware fires them: the
first onset is at the first row that turns the envelope on; each onset is one period after
the previous one, the period being the one in effect at the previous onset; a burst fires at
an onset with the envelope in effect there (none while it is 0). A row between onsets
therefore takes effect at the next onset. The simulated bench renders a program per sample
(:meth:`Program.render`); ``rtlift record`` sends each onset's command just before it.

The standard campaign (docs/BENCH.md; the paper's experiments, defined in Cμ and t⁺ and
turned into volts with the rig's calibration): :func:`standard_program`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from rtlift.core.errors import RecordError
from rtlift.core.rate import FS_HZ
from rtlift.core.wing import CHORD_M as CHORD_M  # the paper's wing and flow
from rtlift.core.wing import CMU_AT_60V as CMU_AT_60V
from rtlift.core.wing import U_INF_M_S as U_INF_M_S

T_CONV_S = CHORD_M / U_INF_M_S
"""Convective time c/U∞ ≈ 0.0817 s (the paper's t_convect); t⁺ = t / T_CONV_S."""

COLUMNS = ("t", "envelope_v", "burst_period_ms")
ENVELOPE_LIMIT_V = 200.0
"""The firmware's limit (PROTOCOL.md: it clamps the envelope to 200 V)."""
TARE_S = 2.0
"""Actuator off before every standard experiment (the tare)."""
OPTIMAL_PERIOD_MS = 125
"""The lift-optimal 8 Hz burst rate (paper: T = 1.56 t⁺)."""
CMU_MAX = 0.022
"""Top of the paper's static map."""
STATIC_RAMP_S = 40.0
STATIC_HOLD_S = 2.0
SINE_CMU_MEAN = 0.011
SINE_CMU_AMPLITUDE = 0.010
TRAIN_BURSTS = 10
TRAIN_REPEATS = 3
TRAIN_REST_TPLUS = 15.0
SINGLE_BURSTS = 20
SINGLE_SPACING_TPLUS = 12.0
RANDOM_S = 58.0


class ProgramError(RecordError):
    """A program file or table that cannot be run (one line naming the file, line and column)."""


def period_ms(t_plus: float) -> int:
    """A burst period of ``t_plus`` convective times in whole ms (the protocol's unit)."""
    return int(round(t_plus * T_CONV_S * 1000.0))


def samples_of_ms(ms: int, fs_hz: float = FS_HZ) -> int:
    """A period in ms as the firmware counts it, in whole samples."""
    return int(round(ms * fs_hz / 1000.0))


def reduced_frequency_hz(k: float, chord_m: float = CHORD_M, u_inf: float = U_INF_M_S) -> float:
    """f = k U∞ / (π c) (paper: k = π f c / U∞)."""
    return k * u_inf / (math.pi * chord_m)


@dataclass(frozen=True)
class Onset:
    """A burst onset of a program: sample index (from the program's start), the envelope (V)
    and the burst period (ms) in effect there."""

    sample: int
    envelope_v: float
    period_ms: int


@dataclass(frozen=True)
class Program:
    """Rows of ``(t, envelope_v, burst_period_ms)`` (module docstring); checked at construction."""

    name: str
    t: np.ndarray
    envelope_v: np.ndarray
    burst_period_ms: np.ndarray
    source: str = "standard"

    def __post_init__(self) -> None:
        t, env, per = self.t, self.envelope_v, self.burst_period_ms
        if not (len(t) == len(env) == len(per)) or len(t) < 2:
            raise ProgramError(f"program {self.name}: at least two rows of t, envelope_v, burst_period_ms")
        if t[0] != 0.0 or np.any(np.diff(t) <= 0):
            raise ProgramError(f"program {self.name}: t must start at 0 and increase strictly")
        if env[-1] != 0.0:
            raise ProgramError(f"program {self.name}: the last row ends the program; its envelope_v must be 0")
        if per[0] <= 0:
            raise ProgramError(f"program {self.name}: the first row must give a burst_period_ms > 0")

    @property
    def duration_s(self) -> float:
        return float(self.t[-1])

    def samples(self, fs_hz: float = FS_HZ) -> int:
        """Length of the program in samples (the last row's time)."""
        return int(round(self.t[-1] * fs_hz))

    def _per_sample(self, fs_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """The envelope (V) and the period (ms, 0 = keep resolved) in effect at each sample."""
        n = self.samples(fs_hz)
        rows = np.searchsorted(np.round(self.t * fs_hz).astype(np.int64), np.arange(n), side="right") - 1
        per = np.asarray(self.burst_period_ms, dtype=np.int64)
        given = np.maximum.accumulate(np.where(per > 0, np.arange(len(per)), 0))
        return np.asarray(self.envelope_v, dtype=float)[rows], per[given][rows]

    def onsets(self, fs_hz: float = FS_HZ) -> list[Onset]:
        """Every burst onset of the program (module docstring), with or without a burst."""
        env, per = self._per_sample(fs_hz)
        on = np.flatnonzero(env > 0)
        out: list[Onset] = []
        k = int(on[0]) if on.size else len(env)
        while k < len(env):
            out.append(Onset(k, float(env[k]), int(per[k])))
            k += max(1, samples_of_ms(int(per[k]), fs_hz))
        return out

    def render(self, fs_hz: float = FS_HZ, burst_samples: int = 4) -> tuple[np.ndarray, np.ndarray]:
        """Per sample: the envelope (V, the control signal as the program gives it) and the burst
        gate (open for ``burst_samples`` from each onset)."""
        env, _ = self._per_sample(fs_hz)
        gate = np.zeros(len(env), dtype=bool)
        for o in self.onsets(fs_hz):
            gate[o.sample:o.sample + burst_samples] = True
        return env, gate

    def write(self, path: str | os.PathLike) -> None:
        """Write the program file (``# program:`` metadata, header, one row per line)."""
        with open(path, "w", encoding="utf-8") as f:
            f.write(f"# program: {self.name}\n" + ",".join(COLUMNS) + "\n")
            for t, v, p in zip(self.t, self.envelope_v, self.burst_period_ms, strict=True):
                f.write(f"{float(t)!r},{float(v)!r},{int(p)}\n")


def read_program(path: str | os.PathLike) -> Program:
    """Read and check a program file; :class:`ProgramError` (one line) on any problem."""
    from rtlift.core.records import _read_table

    try:
        meta, cols = _read_table(path, COLUMNS, 2)
    except RecordError as exc:
        raise ProgramError(str(exc)) from None
    t, env, per = cols["t"], cols["envelope_v"], cols["burst_period_ms"]

    def fail(row: int, message: str) -> ProgramError:
        return ProgramError(f"{path}: data row {row + 1}: {message}")

    if t[0] != 0.0:
        raise fail(0, f"column 't': the program starts at t = 0, got {t[0]:g}")
    for i in range(len(t)):
        if not 0.0 <= env[i] <= ENVELOPE_LIMIT_V:
            raise fail(i, f"column 'envelope_v': {env[i]:g} V is outside 0 … {ENVELOPE_LIMIT_V:g} V")
        if per[i] != int(per[i]) or not 0 <= per[i] <= 0xFFFF:
            raise fail(i, f"column 'burst_period_ms': {per[i]:g} is not a whole number of ms in 0 … 65535")
        if 0 < per[i] < 20:
            raise fail(i, f"column 'burst_period_ms': {per[i]:g} ms is shorter than two bursts (20 ms)")
    if per[0] == 0:
        raise fail(0, "column 'burst_period_ms': the first row must give a period (0 means keep the current one)")
    if env[-1] != 0.0:
        raise fail(len(t) - 1, "column 'envelope_v': the last row ends the program and must be 0 (off)")
    steps = np.round(t * FS_HZ)
    same = np.flatnonzero(np.diff(steps) == 0)
    if same.size:
        raise fail(int(same[0]) + 1, f"column 't': less than one sample ({1e3 / FS_HZ:g} ms) after the row before")
    name = meta.get("program") or os.path.splitext(os.path.basename(os.fspath(path)))[0]
    return Program(name, t, env, per.astype(np.int64), source=os.fspath(path))


# -- the standard campaign -------------------------------------------------------------------
VoltsFromCmu = Callable[[np.ndarray], np.ndarray]


def _from_samples(name: str, env_cmu: np.ndarray, period: int | np.ndarray, volts: VoltsFromCmu,
                  fs_hz: float) -> Program:
    """One row per sample of a per-sample envelope (Cμ), plus the ending row (off)."""
    n = len(env_cmu)
    per = np.broadcast_to(np.asarray(period, dtype=np.int64), (n,))
    t = np.arange(n + 1) / fs_hz
    env_v = np.concatenate([np.asarray(volts(np.asarray(env_cmu, dtype=float)), dtype=float), [0.0]])
    env_v[:-1][np.asarray(env_cmu) <= 0] = 0.0
    return Program(name, t, env_v, np.concatenate([per, per[-1:]]))


def _rows(name: str, rows: list[tuple[int, float, int]], end: int, volts: VoltsFromCmu, fs_hz: float) -> Program:
    """Rows given as (sample, envelope Cμ, period ms), ending at sample ``end``."""
    k = np.array([r[0] for r in rows] + [end])
    cmu = np.array([r[1] for r in rows] + [0.0])
    env_v = np.where(cmu > 0, np.asarray(volts(cmu), dtype=float), 0.0)
    per = np.array([r[2] for r in rows] + [rows[-1][2]], dtype=np.int64)
    return Program(name, k / fs_hz, env_v, per)


def _static(volts: VoltsFromCmu, rng: np.random.Generator, fs_hz: float) -> Program:
    up = int(STATIC_RAMP_S * fs_hz)
    ramp = np.linspace(0.0, CMU_MAX, up + 1)[1:]  # no zero-amplitude burst at the ends
    env = np.concatenate([ramp, np.full(int(STATIC_HOLD_S * fs_hz), CMU_MAX), ramp[::-1],
                          np.zeros(int(TARE_S * fs_hz))])
    return _from_samples("static", env, OPTIMAL_PERIOD_MS, volts, fs_hz)


def _single_burst(volts: VoltsFromCmu, rng: np.random.Generator, fs_hz: float) -> Program:
    spacing = period_ms(SINGLE_SPACING_TPLUS)
    return _rows("single_burst", [(0, CMU_AT_60V, spacing)], SINGLE_BURSTS * samples_of_ms(spacing, fs_hz),
                 volts, fs_hz)


def _train(t_plus: float) -> Callable[[VoltsFromCmu, np.random.Generator, float], Program]:
    def program(volts: VoltsFromCmu, rng: np.random.Generator, fs_hz: float) -> Program:
        period = period_ms(t_plus)
        rest = period_ms(TRAIN_REST_TPLUS)
        on = TRAIN_BURSTS * samples_of_ms(period, fs_hz)
        block = on + samples_of_ms(rest, fs_hz)
        rows = []
        for r in range(TRAIN_REPEATS):
            rows += [(r * block, CMU_AT_60V, period), (r * block + on, 0.0, rest)]
        return _rows(f"train_T{t_plus:g}".replace(".", "p"), rows, TRAIN_REPEATS * block, volts, fs_hz)
    return program


def _sine(k: float, periods: int) -> Callable[[VoltsFromCmu, np.random.Generator, float], Program]:
    def program(volts: VoltsFromCmu, rng: np.random.Generator, fs_hz: float) -> Program:
        f = reduced_frequency_hz(k)
        t = np.arange(int(round(periods / f * fs_hz))) / fs_hz
        env = SINE_CMU_MEAN - SINE_CMU_AMPLITUDE * np.cos(2.0 * math.pi * f * t)
        return _from_samples(f"sine_k{k:g}".replace(".", ""), env, OPTIMAL_PERIOD_MS, volts, fs_hz)
    return program


def _random(volts: VoltsFromCmu, rng: np.random.Generator, fs_hz: float) -> Program:
    from scipy import signal

    n_on = int(RANDOM_S * fs_hz)
    settle = int(4.0 * fs_hz)
    b, a = signal.butter(2, 1.0, fs=fs_hz)
    x = signal.lfilter(b, a, rng.standard_normal(n_on + settle))[settle:]
    x = (x - x.mean()) / x.std()
    env = np.clip(SINE_CMU_MEAN + 0.0055 * x, 0.0005, 0.0215)
    return _from_samples("random", env, OPTIMAL_PERIOD_MS, volts, fs_hz)


@dataclass(frozen=True)
class Experiment:
    name: str
    description: str
    program: Callable[[VoltsFromCmu, np.random.Generator, float], Program]


EXPERIMENTS: Mapping[str, Experiment] = MappingProxyType({
    e.name: e for e in (
        Experiment("static", "slow sweep of the 8 Hz burst amplitude up and down", _static),
        Experiment("single_burst", "isolated bursts at Cμ 0.0022, 12 t⁺ apart", _single_burst),
        Experiment("train_T1p75", "10 bursts at 60 V every 1.75 t⁺, three times", _train(1.75)),
        Experiment("train_T3p5", "10 bursts at 60 V every 3.5 t⁺, three times", _train(3.5)),
        Experiment("train_T7", "10 bursts at 60 V every 7 t⁺, three times", _train(7.0)),
        Experiment("sine_k0125", "sinusoidal envelope, k = 0.125", _sine(0.125, 20)),
        Experiment("sine_k025", "sinusoidal envelope, k = 0.25", _sine(0.25, 40)),
        Experiment("random", "band-limited random envelope", _random),
    )
})
CAMPAIGN = tuple(EXPERIMENTS)
"""All eight, in the order a campaign records them."""


def check_seed(seed: object) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise RecordError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def standard_program(name: str, volts: VoltsFromCmu, seed: int = 0, fs_hz: float = FS_HZ) -> Program:
    """One experiment of the standard campaign; ``volts`` maps Cμ to the drive amplitude (the
    rig's calibration: ``Calibration.volts_from_cmu``), ``seed`` draws the random envelope."""
    if name not in EXPERIMENTS:
        raise ProgramError(f"unknown experiment {name!r} (known: {', '.join(EXPERIMENTS)})")
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([check_seed(seed), 1])))
    return EXPERIMENTS[name].program(volts, rng, fs_hz)
