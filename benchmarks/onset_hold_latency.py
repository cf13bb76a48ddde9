"""The model step with the ``onset_hold`` input stage: compiled step and batch, against the same model
with a fade only (issue 47's follow-up: the hold's own slot in the compiled step).

The benchmark model of :mod:`benchmarks.step_latency` (300-sample kernel, order-2 Wiener part,
order-2 high-pass) with the input stages of ``rtlift identify --envelope delivered`` and what
the diagnosis appends to it: ``delay_hold`` ([delay 2 samples, onset_hold]),
``delay_hold_fade`` (then an ``actuator_fade``), and ``delay_fade`` (no hold) to compare. Prints
JSON as its last line, per model: ``compiled`` (whether ``HybridModel.step`` is the compiled
step), and then :func:`benchmarks.step_latency.measure`'s figures (step_median_us, step_p99_us
of the compiled step, the reference step's, batch_seconds, max_abs_difference ...); a model
that takes the reference step gets only the reference step's median and p99 (µs).
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks._common import emit  # noqa: E402
from benchmarks.step_latency import _latency, arguments, benchmark_case, measure  # noqa: E402
from rtlift.blocks.actuator_fade import ActuatorFade  # noqa: E402
from rtlift.blocks.delay import Delay  # noqa: E402
from rtlift.blocks.onset_hold import OnsetHold  # noqa: E402
from rtlift.core.rate import FS_HZ  # noqa: E402

ORDERS = {"delay_hold": "DH", "delay_hold_fade": "DHF", "delay_fade": "DF"}


def _stages(order: str) -> tuple:
    """D: a 2-sample delay, H: the hold, F: a fade (f = 0.6, τ = 0.5 s on the bursts' clock)."""
    made = {"D": lambda: Delay(2 / FS_HZ, FS_HZ), "H": lambda: OnsetHold(FS_HZ),
            "F": lambda: ActuatorFade(0.6, 0.5, FS_HZ)}
    return tuple(made[c]() for c in order)


def main() -> None:
    args = arguments(__doc__.splitlines()[0], minutes=2.0, steps=20_000)
    _, base, cmu, env = benchmark_case(args.minutes)
    out: dict = {"samples": cmu.size, "kernel_len": 300}
    for name, order in ORDERS.items():
        model = base.copy()
        model.input_stages = _stages(order)
        if model.compiled:
            out[name] = {"compiled": True, **measure(model, cmu, env, args.steps)}
        else:
            median, p99 = _latency(model.reference_step, cmu[:args.steps], env[:args.steps])
            out[name] = {"compiled": False, "reference_step_median_us": round(median, 3),
                         "reference_step_p99_us": round(p99, 3)}
    emit(out)


if __name__ == "__main__":
    main()
