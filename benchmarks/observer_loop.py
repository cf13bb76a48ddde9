"""The observer loop live: bench emulator on a pseudo-terminal → serial link → observer.

The simulated DAQ runs in its own process (``rtlift bench serve --serial``, the ``random``
experiment at 400 Hz); this process opens the pty with firmware_io, converts, and steps the
observer once per received sample, as ``rtlift observe`` does. Prints JSON as its last line:
``observer_step_median_us``, ``observer_step_p99_us`` (one ``Observer.step``),
``loop_latency_p50_ms``, ``loop_latency_p99_ms`` (sample receipt → estimate),
``lost_samples``, ``seconds``; plus the other link counters and a tracemalloc measurement of
one step (bytes retained after 2000 steps, transient peak). Before the link opens the observer
is warmed up (``observer_warm_up_s``: numba compiles or loads its cache; ``observer_compiled``)
and timed in a tight loop over a recorded ``random`` record, in the same run:
``observer_step_tight_median_us``/``_p99_us`` (``Observer.step``),
``observer_reference_step_tight_median_us`` (the numpy/BLAS reference step) and
``filterpy_step_tight_median_us``/``_p99_us`` (filterpy's ``predict`` + ``update`` at the same
state dimension, the filter alone). Targets (issue 14): live step median ≤ 15 µs, p99 ≤ 60 µs,
latency p99 ≤ 1 ms, 0 lost. Measured, not asserted.

``--load`` runs the loop under load: a CPU hog pinned to the other core (this process is
pinned to core 0 when the machine has two or more) and bursts of disk writes (``--burst-mb``
MB written and fsync'd every ``--burst-every`` s into a temporary directory), both in their
own processes; the JSON gains ``load`` (what the hog and the writer did).

``--spin`` alternates four phases in one run (``PAIRS`` times each, ``--seconds`` in all):
sleeping in the kernel between samples; spinning on the port; spinning while the observer
keeps its working set in the cache between polls (``Observer.touch``: ``rtlift observe
--spin``); and sleeping until ``SPIN_WINDOW_S`` before each sample is due, then spinning with
the touch (``rtlift observe --spin 0.5``). The JSON gains ``spin``, ``spin_touch`` and
``spin_tail`` with the same keys; every phase has ``cpu_share``, this process's CPU time over
the phase's wall time.

``--view`` runs the same live loop with the live view up (``rtlift.app.view.LiveView``, the tap
fed once per sample) and a headless Chromium showing the page: after a warm-up (not counted)
that lasts until the samples queued while the browser started are consumed, the run
alternates phases without and with the tap (off, view, four times; ``--seconds`` of each in
all; same link, same observer, server and browser up throughout),
so both are measured in one run under the same machine load; the JSON keeps the keys above
for the phases without the view and gains ``view`` (the same keys with it) and
``view_server`` (batches sent, pages, batches dropped).

``--monitor`` runs the same live loop alternately without and with the departure monitor
(:class:`rtlift.observer.monitor.DepartureMonitor` on the loop, as ``rtlift observe`` has it on by
default; ``PAIRS`` pairs, ``--seconds`` of each in all, same link, same observer): the JSON keeps
the keys above for the phases without it and gains ``monitor`` (the same keys with it, plus the
monitor's own per-call times: ``monitor_step_median_us``/``_p99_us`` over the samples that end no
block, ``monitor_block_end_median_us``/``_max_us`` over those that do, and the observer step's
p99 on the sample right after a block end, ``observer_step_after_block_p99_us``) and ``gc`` (the
interpreter's garbage collections per generation in each condition). Needs a model file with a
fingerprint (``--model``, e.g. one from ``rtlift identify``).

``--anatomy`` (issue 46, third pass) asks what the live step's p99 is made of. It alternates, in
one run on the same link (``PAIRS`` rounds, ``--seconds`` in all), the step as it was before
(``dispatch``: numba's dispatcher called with the 20 arrays one by one), the step as it is
(``at``: the arrays bound by address, :mod:`rtlift.observer.compiled_at`), the same with the
interpreter's switch interval at 50 µs instead of 5 ms (``at_switch50us``), the same with the loop
asleep until ``SPIN_WINDOW_S`` before each sample is due and then spinning with ``Observer.touch``
(``at_spin_tail``: ``rtlift observe --spin 0.5``, the core kept warm) and the same with the
loop's thread under ``SCHED_FIFO`` (``at_fifo``: no other process's thread preempts it; only where
the system allows it, else the condition is left out). Each step is timed as
the loop times it (``perf_counter`` around ``Observer.step`` and nothing else) and, outside that
pair, by the thread's CPU clock (``time.thread_time``) and ``getrusage(RUSAGE_THREAD)``
(involuntary and voluntary context switches, minor faults). Per condition the JSON's
``anatomy`` has the step's median/p99, the CPU time over the slowest 1 % of steps against their
wall time, the context switches and faults inside them, how long the sample had waited since its
receipt when its step began (``wait_*``: the host's decode and conversion), and how long the loop
had been away since the previous step (``away_*``). ``threads`` lists the process's Python
threads and its OS threads (a reader thread would show here). The tight-loop figures gain the
dispatcher's step (``observer_step_tight_dispatch_*``). ``anatomy.after_sleep``: without link or
emulator, the step right after a 2.4 ms sleep and the step right after that one, both ways
alternated (:func:`after_sleep`).

``--model MODEL.json`` uses a model file with observer settings; by default the model is
identified from the bench (seed 1, 2nd-order Wiener) and the observer tuned on a seed-1
``random`` record first (≈ 15 s, not timed).
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import time
import tracemalloc

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks._common import emit, percentiles_us  # noqa: E402


class TimedMonitor:
    """The departure monitor as the loop steps it, each ``step`` call timed (s) into preallocated
    arrays with whether it ended a block (the once-a-second statistics); nothing else changes."""

    def __init__(self, monitor, capacity: int) -> None:
        self.monitor = monitor
        self.times = np.zeros(capacity)
        self.block_end = np.zeros(capacity, dtype=bool)
        self.n = 0

    def step(self, dcl, model_dcl: float, innovation: float, envelope: float = math.nan) -> None:
        mon, k = self.monitor, self.n
        nb = mon._nb
        t0 = time.perf_counter()
        mon.step(dcl, model_dcl, innovation, envelope)
        dt = time.perf_counter() - t0
        if k < self.times.size:
            self.times[k] = dt
            self.block_end[k] = mon._nb != nb
            self.n = k + 1


def default_model():
    from hil_sim.experiments import run_experiment
    from rtlift.identify.campaign import IdentifyOptions, identify_hybrid
    from rtlift.observer import tune_observer

    recs = {n: run_experiment(n, seed=1).to_record() for n in ("static", "single_burst", "sine_k0125", "random")}
    model = identify_hybrid(recs["static"], recs["single_burst"], recs["sine_k0125"], IdentifyOptions(order=2)).model
    model.observer_config = tune_observer(model, [recs["random"]])
    return model


def allocation(model) -> dict:
    """tracemalloc around 2000 steps after a warm-up: retained and transient bytes."""
    from hil_sim.experiments import run_experiment
    from rtlift.observer import Observer

    rec = run_experiment("random", seed=4).to_record()
    obs = Observer.from_model(model)
    c, e, z = rec.cmu.tolist(), rec.cmu_envelope.tolist(), rec.dcl.tolist()
    for k in range(1000):
        obs.step(c[k], e[k], z[k])
    tracemalloc.start()
    for k in range(1000, 3000):
        obs.step(c[k], e[k], z[k])
    current, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return {"alloc_retained_bytes_after_2000_steps": current, "alloc_transient_peak_bytes": peak - current}


def tight_loop(model, steps: int = 8000) -> dict:
    """Single calls timed back to back (caches warm): the compiled step, the reference step and
    filterpy's predict + update with the observer's F, B, Q, R and a row of the same size."""
    from filterpy.kalman import KalmanFilter

    from hil_sim.experiments import run_experiment
    from rtlift.observer import Observer

    rec = run_experiment("random", seed=4).to_record()
    c, e, z = rec.cmu.tolist(), rec.cmu_envelope.tolist(), rec.dcl.tolist()
    n = min(steps, len(c) - 1000)
    pc = time.perf_counter

    def timed(step) -> tuple[float, float]:
        for k in range(1000):
            step(c[k], e[k], z[k])
        durations = np.empty(n)
        for i, k in enumerate(range(1000, 1000 + n)):
            t0 = pc()
            step(c[k], e[k], z[k])
            durations[i] = pc() - t0
        return percentiles_us(durations)

    obs = Observer.from_model(model)
    obs.warm_up()
    median, p99 = timed(obs.step)
    bound, obs._at = obs._at, ()                      # the dispatcher, the arrays one by one
    dispatch_median, dispatch_p99 = timed(obs.step)
    obs._at = bound
    ref_median, ref_p99 = timed(Observer.from_model(model).reference_step)
    kf = KalmanFilter(dim_x=obs.layout.dim_x, dim_z=1, dim_u=1)
    kf.F, kf.B, kf.Q, kf.R = obs.kf.F, obs.kf.B, obs.kf.Q, obs.kf.R
    kf.P = obs.layout.P0(obs.config)
    H = obs.layout.h_fixed.reshape(1, -1).copy()
    H[0, :obs.layout.n_wiener] = obs.layout.C

    def filterpy_step(cmu: float, env: float, dcl: float) -> None:
        kf.predict(u=np.array([env]))
        kf.update(np.array([dcl]), H=H)

    fp_median, fp_p99 = timed(filterpy_step)
    return {"observer_step_tight_median_us": round(median, 2), "observer_step_tight_p99_us": round(p99, 2),
            "observer_step_tight_dispatch_median_us": round(dispatch_median, 2),
            "observer_step_tight_dispatch_p99_us": round(dispatch_p99, 2),
            "observer_reference_step_tight_median_us": round(ref_median, 2),
            "observer_reference_step_tight_p99_us": round(ref_p99, 2),
            "filterpy_step_tight_median_us": round(fp_median, 2), "filterpy_step_tight_p99_us": round(fp_p99, 2)}


class StepAnatomy:
    """The observer as the loop steps it, each step timed as :class:`~rtlift.app.live.ObserverLoop`
    times it (``perf_counter`` around ``Observer.step``) and, outside that pair, by the thread's
    CPU clock and ``getrusage(RUSAGE_THREAD)``; rows in a preallocated array (s and counts):
    wall, CPU, involuntary and voluntary context switches, minor faults, wait since the sample's
    receipt, time away since the previous step. ``converter`` wraps the loop's converter to see
    each sample's receipt time."""

    COLUMNS = ("wall", "cpu", "nivcsw", "nvcsw", "minflt", "wait", "away")

    def __init__(self, observer, converter, capacity: int) -> None:
        import resource

        self.observer, self._convert = observer, converter
        self.rows = np.zeros((capacity, len(self.COLUMNS)))
        self.n = 0
        self._received = 0.0
        self._end = None
        self._rusage = lambda: resource.getrusage(resource.RUSAGE_THREAD)

    def converter(self, sample):
        self._received = sample.host_time
        return self._convert(sample)

    def step(self, cmu, env, dcl):
        pc, k = time.perf_counter, self.n
        r0, c0 = self._rusage(), time.thread_time()
        t0 = pc()
        est = self.observer.step(cmu, env, dcl)
        t1 = pc()
        c1, r1 = time.thread_time(), self._rusage()
        if k < self.rows.shape[0]:
            self.rows[k] = (t1 - t0, c1 - c0, r1.ru_nivcsw - r0.ru_nivcsw, r1.ru_nvcsw - r0.ru_nvcsw,
                            r1.ru_minflt - r0.ru_minflt, t0 - self._received,
                            t0 - self._end if self._end is not None else np.nan)
            self.n = k + 1
        self._end = t1
        return est


def after_sleep(model, steps: int = 1200, sleep_s: float = 0.0024) -> dict:
    """No link, no other process: the observer step on a recorded ``random`` record right after
    the thread slept ``sleep_s`` (as the live loop does between samples), and the next step right
    after it, the dispatcher's and the by-address step alternated per wake-up; median and p99 (µs)."""
    from hil_sim.experiments import run_experiment
    from rtlift.observer import Observer

    rec = run_experiment("random", seed=4).to_record()
    c, e, z = rec.cmu.tolist(), rec.cmu_envelope.tolist(), rec.dcl.tolist()
    obs = Observer.from_model(model)
    obs.warm_up()
    bound, pc = obs._at, time.perf_counter
    times = {(w, i): np.empty(steps) for w in ("dispatch", "at") for i in (0, 1)}
    for j in range(2 * steps):
        way = ("dispatch", "at")[j % 2]
        obs._at = () if way == "dispatch" else bound
        time.sleep(sleep_s)
        for i in (0, 1):
            k = (2 * j + i) % len(c)
            t0 = pc()
            obs.step(c[k], e[k], z[k])
            times[(way, i)][j // 2] = pc() - t0
    obs._at = bound
    out = {}
    for (way, i), t in times.items():
        median, p99 = percentiles_us(t)
        name = f"{way}_{'first' if i == 0 else 'second'}"
        out[f"{name}_median_us"], out[f"{name}_p99_us"] = round(median, 2), round(p99, 2)
    return out


ANATOMY = ("dispatch", "at", "at_switch50us", "at_spin_tail", "at_fifo")
"""``--anatomy``'s conditions, alternated (module docstring)."""


def _fifo(on: bool) -> bool:
    """This thread under ``SCHED_FIFO`` (priority 10) or back under ``SCHED_OTHER``; False where the
    system refuses it (no root or CAP_SYS_NICE) or has no such policy."""
    try:
        if on:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
        else:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (AttributeError, OSError):
        return False
    return True


def run_anatomy(link, observer, fs_hz: float, seconds: float) -> dict:
    """``--anatomy``: the conditions of :data:`ANATOMY` alternated ``PAIRS`` times on one link; per
    condition the figures of :func:`anatomy_figures`, and the process's threads."""
    import threading

    from firmware_io import Converter
    from rtlift.app.live import ObserverLoop

    converter, stream = Converter(), link.samples(0.5)
    bound, switch = observer._at, sys.getswitchinterval()
    conditions = ANATOMY if _fifo(False) and _fifo(True) and _fifo(False) else ANATOMY[:-1]
    n = int(round(seconds * fs_hz)) // (PAIRS * len(conditions))
    rows: dict[str, list] = {c: [] for c in conditions}
    lost = dict.fromkeys(conditions, 0)
    ObserverLoop(observer, converter, link.seq_modulus, fs_hz=fs_hz, max_samples=int(fs_hz)).run(stream)  # warm-up
    try:
        for condition in conditions * PAIRS:
            observer._at = () if condition == "dispatch" else bound
            sys.setswitchinterval(5e-5 if condition == "at_switch50us" else switch)
            _fifo(condition == "at_fifo")
            link.spin = condition == "at_spin_tail"          # rtlift observe --spin 0.5
            link.on_idle = observer.touch if link.spin else None
            link.spin_window_s = SPIN_WINDOW_S if link.spin else None
            probe = StepAnatomy(observer, converter, n)
            lost0 = link.counters.lost
            ObserverLoop(probe, probe.converter, link.seq_modulus, fs_hz=fs_hz, max_samples=n).run(
                stream, silence_s=10.0)
            rows[condition].append(probe.rows[:probe.n])
            lost[condition] += link.counters.lost - lost0
    finally:
        observer._at = bound
        sys.setswitchinterval(switch)
        _fifo(False)
        link.spin, link.on_idle, link.spin_window_s = False, None, None
    tasks = sorted(os.listdir("/proc/self/task")) if os.path.isdir("/proc/self/task") else []
    names = []
    for t in tasks:
        try:
            with open(f"/proc/self/task/{t}/comm") as f:
                names.append(f.read().strip())
        except OSError:
            names.append("?")
    return {"threads": {"python": [t.name for t in threading.enumerate()], "os_threads": names},
            **{c: {**anatomy_figures(np.concatenate(rows[c])), "lost_samples": lost[c]} for c in conditions}}


def anatomy_figures(rows: np.ndarray) -> dict:
    """Step median/p99 (µs), and over the slowest 1 % of steps: their median wall and CPU time,
    the context switches and minor faults inside them; the wait since receipt and the time away
    (median, p99, and the slow steps' median)."""
    col = {c: rows[:, i] for i, c in enumerate(StepAnatomy.COLUMNS)}
    wall = col["wall"] * 1e6
    p99 = float(np.percentile(wall, 99))
    slow = wall >= p99
    q = lambda v, p: round(float(np.nanpercentile(v, p)), 2)  # noqa: E731
    return {"steps": int(wall.size), "step_median_us": q(wall, 50), "step_p99_us": round(p99, 2),
            "step_max_us": round(float(wall.max()), 1),
            "cpu_median_us": q(col["cpu"] * 1e6, 50),
            "slow_steps": int(slow.sum()), "slow_wall_median_us": q(wall[slow], 50),
            "slow_cpu_median_us": q(col["cpu"][slow] * 1e6, 50),
            "slow_with_involuntary_switch": int((col["nivcsw"][slow] > 0).sum()),
            "involuntary_switches_in_steps": int(col["nivcsw"].sum()),
            "voluntary_switches_in_steps": int(col["nvcsw"].sum()),
            "minor_faults_in_steps": int(col["minflt"].sum()),
            "wait_median_us": q(col["wait"] * 1e6, 50), "wait_p99_us": q(col["wait"] * 1e6, 99),
            "slow_wait_median_us": q(col["wait"][slow] * 1e6, 50),
            "away_median_ms": q(col["away"] * 1e3, 50), "slow_away_median_ms": q(col["away"][slow] * 1e3, 50)}


HOG = "import time\nend = time.perf_counter() + {s}\nn = 0\nwhile time.perf_counter() < end:\n    n += 1\nprint(n)"
WRITER = """
import os, sys, time
d, mb, every, seconds = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
block = os.urandom(1 << 20)
end = time.perf_counter() + seconds
written = bursts = 0
worst = 0.0
while time.perf_counter() < end:
    t = time.perf_counter()
    with open(os.path.join(d, "burst.bin"), "wb") as f:
        for _ in range(mb):
            f.write(block)
        f.flush()
        os.fsync(f.fileno())
    worst = max(worst, time.perf_counter() - t)
    written += mb
    bursts += 1
    time.sleep(max(0.0, every - (time.perf_counter() - t)))
print(written, bursts, round(worst, 3))
"""


def start_load(seconds: float, burst_mb: int, burst_every: float, tmp: str) -> list[subprocess.Popen]:
    """The CPU hog (on the last core) and the disk writer, for ``seconds``."""
    cpus = sorted(os.sched_getaffinity(0))
    hog = subprocess.Popen([sys.executable, "-c", HOG.format(s=seconds)], stdout=subprocess.PIPE, text=True)
    if len(cpus) >= 2:
        os.sched_setaffinity(hog.pid, {cpus[-1]})
        os.sched_setaffinity(0, {cpus[0]})
    writer = subprocess.Popen([sys.executable, "-c", WRITER, tmp, str(burst_mb), str(burst_every), str(seconds)],
                              stdout=subprocess.PIPE, text=True)
    return [hog, writer]


def stop_load(procs: list[subprocess.Popen]) -> dict:
    hog, writer = procs
    out = {}
    for name, p in (("hog", hog), ("writer", writer)):
        try:
            text, _ = p.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            p.kill()
            text, _ = p.communicate()
        out[name] = text.split()
    n = out["hog"]
    w = out["writer"]
    return {"cpu_hog_iterations": int(n[0]) if n else None,
            "disk_mb_written": int(w[0]) if w else None, "disk_bursts": int(w[1]) if w else None,
            "disk_burst_worst_s": float(w[2]) if w else None}


PAIRS = 4
SPIN_WINDOW_S = 0.0005
"""``--view``: the run alternates this many (without, with) pairs of phases."""


def run_phases(link, observer, fs_hz: float, seconds: float, view_dir: str | None, spin: bool = False,
               monitor: TimedMonitor | None = None) -> dict:
    """The live loop for ``seconds`` of device time; with ``view_dir`` (a scratch folder for the
    browser's profile) alternately without and with the view's tap, ``seconds`` of each; with
    ``monitor`` alternately without and with it."""
    import gc

    from firmware_io import Converter
    from firmware_io.latency import LatencyRecorder
    from rtlift.app.live import ObserverLoop

    converter = Converter()
    stream = link.samples(0.5)
    runs = {c: {"samples": 0, "lost": 0, "wall": 0.0, "cpu": 0.0, "steps": [], "latencies": LatencyRecorder(),
                "gc": [0, 0, 0], "after_block": []}
            for c in ("warm-up", "off", "view", "spin", "spin_touch", "spin_tail", "monitor")}

    def phase(condition: str, n: int, tap, mon: TimedMonitor | None = None) -> None:
        lost0 = link.counters.lost
        loop = ObserverLoop(observer, converter, link.seq_modulus, fs_hz=fs_hz, max_samples=n, time_steps=True,
                            tap=tap, monitor=mon)
        k0 = mon.n if mon is not None else 0
        gc0 = [g["collections"] for g in gc.get_stats()]
        t0, c0 = time.perf_counter(), time.process_time()
        loop.run(stream, silence_s=10.0)
        r = runs[condition]
        r["gc"] = [a + g["collections"] - b for a, g, b in zip(r["gc"], gc.get_stats(), gc0, strict=True)]
        if mon is not None and loop.stats.filled == 0:     # step i+1 follows monitor call i
            steps = np.frombuffer(loop.stats.step_times, dtype=float)
            ends = mon.block_end[k0:k0 + steps.size - 1]
            r["after_block"].append(steps[1:][ends])
        r["wall"] += time.perf_counter() - t0
        r["cpu"] += time.process_time() - c0
        r["samples"] += loop.stats.samples
        r["lost"] += link.counters.lost - lost0
        r["steps"].append(np.frombuffer(loop.stats.step_times, dtype=float))
        h = r["latencies"]
        for i, c in enumerate(loop.stats.latencies.counts):
            h.counts[i] += c
        h.n += loop.stats.latencies.n

    n = int(round(seconds * fs_hz))
    if monitor is not None:
        for condition in ("off", "monitor") * PAIRS:          # alternated: same load
            phase(condition, n // PAIRS, None, monitor if condition == "monitor" else None)
        return runs
    if spin:
        for condition in ("off", "spin", "spin_touch", "spin_tail") * PAIRS:   # alternated: same load
            link.spin = condition != "off"
            link.on_idle = observer.touch if condition in ("spin_touch", "spin_tail") else None
            link.spin_window_s = SPIN_WINDOW_S if condition == "spin_tail" else None
            phase(condition, n // PAIRS, None)
        link.spin, link.on_idle, link.spin_window_s = False, None, None
        return runs
    if view_dir is None:
        phase("off", n, None)
        return runs
    from rtlift.app.view import LiveView
    from rtlift.app.view.browser import HeadlessPage

    view = LiveView(0, title="benchmarks/observer_loop.py --view", fs_hz=fs_hz,
                    counters=lambda: link.counters.as_dict()).start()
    try:
        with HeadlessPage(view.url, os.path.join(view_dir, "chromium-profile")) as page:
            deadline = time.perf_counter() + 30.0
            while view.pages_connected < 1:
                if time.perf_counter() > deadline or page.proc.poll() is not None:
                    raise RuntimeError("the headless browser did not open the live view")
                time.sleep(0.05)
            for _ in range(20):                            # until the backlog queued while the browser started is gone
                wall = runs["warm-up"]["wall"]
                phase("warm-up", int(fs_hz / 2), None)
                if runs["warm-up"]["wall"] - wall > 0.45:
                    break
            for condition in ("off", "view") * PAIRS:
                phase(condition, n // PAIRS, view.tap if condition == "view" else None)
            runs["view_server"] = {**view.stats, "pages_connected_at_end": view.pages_connected}
    finally:
        view.close()
    return runs


def loop_figures(run: dict) -> dict:
    """Step and latency percentiles of one condition, in the JSON's units."""
    step_median, step_p99 = percentiles_us(np.concatenate(run["steps"]))
    h = run["latencies"]
    return {"observer_step_median_us": round(step_median, 2), "observer_step_p99_us": round(step_p99, 2),
            "loop_latency_p50_ms": round(h.percentile(50) * 1e3, 4),
            "loop_latency_p99_ms": round(h.percentile(99) * 1e3, 4),
            "lost_samples": run["lost"], "samples": run["samples"], "seconds": round(run["wall"], 2),
            "cpu_share": round(run["cpu"] / run["wall"], 3) if run["wall"] > 0 else None}


def monitor_figures(run: dict, mon: TimedMonitor) -> dict:
    """The monitor's own per-call times and the observer step right after a block end (µs)."""
    t, ends = mon.times[:mon.n] * 1e6, mon.block_end[:mon.n]
    after = np.concatenate(run["after_block"]) * 1e6 if run["after_block"] else np.zeros(0)
    return {"monitor_step_median_us": round(float(np.median(t[~ends])), 2),
            "monitor_step_p99_us": round(float(np.percentile(t[~ends], 99)), 2),
            "monitor_block_end_median_us": round(float(np.median(t[ends])), 1) if ends.any() else None,
            "monitor_block_end_max_us": round(float(t[ends].max()), 1) if ends.any() else None,
            "monitor_block_ends": int(ends.sum()),
            "observer_step_after_block_p99_us": round(float(np.percentile(after, 99)), 2) if after.size else None,
            "observer_step_after_block_n": int(after.size)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="device seconds to run (default 20)")
    ap.add_argument("--model", help="model file with observer settings (default: identify and tune)")
    ap.add_argument("--load", action="store_true", help="run under a CPU hog on the other core and disk bursts")
    ap.add_argument("--burst-mb", type=int, default=64, help="MB per disk burst with --load (default 64)")
    ap.add_argument("--burst-every", type=float, default=1.0, help="seconds between disk bursts (default 1)")
    ap.add_argument("--view", action="store_true", help="also run with the live view and a headless Chromium on it")
    ap.add_argument("--monitor", action="store_true",
                    help="also run with the departure monitor on the loop, alternating (needs --model)")
    ap.add_argument("--spin", action="store_true",
                    help="also run with the link busy-polling the port (rtlift observe --spin), alternating")
    ap.add_argument("--anatomy", action="store_true",
                    help="what the live step's p99 is made of: the dispatcher's step, the step by address and "
                         "a 50 us switch interval alternated, each step's CPU time and context switches")
    args = ap.parse_args()
    import tempfile

    from firmware_io import open_link
    from rtlift.model.modelfile import load_model
    from rtlift.observer import Observer

    model = load_model(args.model) if args.model else default_model()
    timed = None
    if args.monitor:
        from rtlift.observer.monitor import DepartureMonitor

        timed = TimedMonitor(DepartureMonitor.for_model(model), int(args.seconds * model.fs_hz) + 1000)
    observer = Observer.from_model(model)
    warm_up_s = observer.warm_up()
    tight = tight_loop(model)
    serve = subprocess.Popen([sys.executable, "-m", "rtlift", "bench", "serve", "--serial", "--experiment", "random",
                              "--seed", "3"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    load = None
    tmp = tempfile.TemporaryDirectory()
    try:
        path = serve.stdout.readline().strip()
        if args.load:
            load = start_load((2 if args.view else 1) * args.seconds + 2.0, args.burst_mb, args.burst_every, tmp.name)
        with open_link({"kind": "serial", "port": path}) as link:
            if args.anatomy:
                anatomy = run_anatomy(link, observer, model.fs_hz, args.seconds)
            runs = run_phases(link, observer, model.fs_hz, args.seconds, tmp.name if args.view else None,
                              spin=args.spin, monitor=timed)
            counters = link.counters.as_dict()
    finally:
        serve.terminate()
        serve.wait(10)
        load_stats = stop_load(load) if load is not None else None
        tmp.cleanup()
    result = {
        **loop_figures(runs["off"]),
        "state_dim": observer.layout.dim_x,
        "observer_compiled": observer.compiled,
        "observer_warm_up_s": round(warm_up_s, 3),
        **tight,
        **{k: v for k, v in counters.items() if k != "lost"},
        **allocation(model),
    }
    if timed is not None:
        result["monitor"] = {**loop_figures(runs["monitor"]), **monitor_figures(runs["monitor"], timed)}
        result["gc"] = {"off": runs["off"]["gc"], "monitor": runs["monitor"]["gc"]}
        result["lost_samples"] = counters["lost"]
    elif args.spin:
        result["spin"] = loop_figures(runs["spin"])
        result["spin_touch"] = loop_figures(runs["spin_touch"])
        result["spin_tail"] = loop_figures(runs["spin_tail"])
        result["lost_samples"] = counters["lost"]
    elif args.view:
        result["lost_samples"] = runs["off"]["lost"] + runs["warm-up"]["lost"]
        result["view"] = loop_figures(runs["view"])
        result["view_server"] = runs["view_server"]
    else:
        result["lost_samples"] = counters["lost"]
    if load_stats is not None:
        result["load"] = load_stats
    if args.anatomy:
        result["anatomy"] = {**anatomy, "after_sleep": after_sleep(model)}
    emit(result)


if __name__ == "__main__":
    main()
