"""``rtlift bench serve --serial | --slcan [--experiment NAME] [--effect SPEC]... [--fault SPEC]...
[--seed N] [--protocol 1|2] [--speed X] [--gust F:A,...]``: run the simulated DAQ on a new
pseudo-terminal, print its path (one line, flushed), stream at 400 Hz until SIGINT or SIGTERM.

``--serial`` emulates the DAQ's serial link (open the path with ``--serial PATH``);
``--slcan`` emulates a USB–CAN adapter with the DAQ behind it (``--can slcan:PATH``).
Effects are plant effects (``hil_sim.effects.parse_effect``); faults are link faults
(:mod:`hil_sim.devices.faults`, e.g. ``corrupt:rate=1e-3``, ``disconnect:after_s=30``) and
command faults (``cmd_drop:rate=0.05``, ``cmd_corrupt:rate=0.05``,
``cmd_late:rate=0.05,delay_ms=50``), on both devices.

The device is a protocol-version-2 device and a real-time HIL plant (:mod:`hil_sim.hil`): it
streams the experiment as version 1 until the first command, then the simulated plant follows
the commanded envelope and burst period from the next burst onset. ``--protocol 1`` serves a
version-1 device instead (it reads no commands). ``--speed X`` paces the samples X times
faster than real time (the device's clock still counts 400 Hz; the watchdog keeps host time).
``--gust F:A,...`` adds Σ A sin(2π F t) to the plant's true ΔCL (:mod:`hil_sim.gust`), t the
device clock: a disturbance for ``rtlift control`` to reject.

It serves session after session ("leave it running"): each host that opens the port (serial:
seen as the pty's hang-up ending; SLCAN: the channel opened) finds the command side in its
power-on state (:meth:`hil_sim.devices.host_control.HostControl.new_session`: no command
applied, actuator off, no ``cmd_seq`` history), and a watchdog trip clears at the next valid
command. The plant goes on between sessions (the flow relaxes with the actuator off), and the
serial DAQ's clock runs whether or not anybody reads it: what it samples with the port closed is
never sent (``samples_unread`` on the stop line), as a USB DAQ's.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from hil_sim import FS_HZ
from hil_sim.devices import SerialDaq, SlcanAdapter, parse_faults
from rtlift.core.errors import UserError
from rtlift.core.rate import PERIOD_S

DEFAULT_EXPERIMENT = "random"


def serve_main(args: argparse.Namespace) -> int:
    """Run the emulator until SIGINT/SIGTERM; 0 on a clean stop, 1 if the device failed."""
    from hil_sim.effects import parse_effect
    from hil_sim.experiments import EXPERIMENTS
    from hil_sim.gust import parse_gust
    from hil_sim.hil import HilStream

    experiment = getattr(args, "experiment", None) or DEFAULT_EXPERIMENT
    if experiment not in EXPERIMENTS:
        raise UserError(f"unknown experiment {experiment!r} (known: {', '.join(EXPERIMENTS)})")
    effects = [parse_effect(spec) for spec in (getattr(args, "effect", None) or [])]
    faults = parse_faults(getattr(args, "fault", None) or [])
    seed = int(getattr(args, "seed", 0) or 0)
    speed = float(getattr(args, "speed", None) or 1.0)
    if not 0.1 <= speed <= 20.0:
        raise UserError(f"bench serve: --speed must be between 0.1 and 20, got {speed:g}")
    protocol = int(getattr(args, "protocol", None) or 2)
    if protocol not in (1, 2):
        raise UserError(f"bench serve: --protocol must be 1 or 2, got {protocol}")
    gust = parse_gust(getattr(args, "gust", None))
    chunks = HilStream(experiment, seed=seed, effects=effects, gust=gust,
                       plant_draw=int(getattr(args, "plant_draw", 0) or 0))  # hil_sim.family
    pace = FS_HZ * speed
    if getattr(args, "slcan", False):
        device = SlcanAdapter(chunks, faults=faults, seed=seed, fs_hz=pace, clock_hz=FS_HZ)
        how = "slcan"
    elif getattr(args, "serial", False):
        device = SerialDaq(chunks, faults=faults, seed=seed, fs_hz=pace, period_us=int(round(1e6 * PERIOD_S)),
                           unread_lost=True)
        how = "serial"
    else:
        raise UserError("bench serve: give --serial or --slcan")
    device.control.accepts_commands = protocol == 2
    chunks.control = device.control

    stop = threading.Event()

    def _stop(signum: int, frame: object) -> None:
        stop.set()

    previous = {sig: signal.signal(sig, _stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        with device:
            device.start()
            print(device.path, flush=True)
            print(f"rtlift bench serve: {how} DAQ on {device.path}, protocol version {protocol}, "
                  f"experiment {experiment}, {FS_HZ:g} Hz at {speed:g}x real time"
                  + (f", gust {gust.spec()}" if gust else "")
                  + (f", plant draw {chunks.meta['plant_draw']}" if "plant_draw" in chunks.meta else "")
                  + "; Ctrl-C stops",
                  file=sys.stderr, flush=True)
            while not stop.is_set() and not device.finished.is_set():
                stop.wait(0.2)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    stats = " ".join(f"{k}={v}" for k, v in device.stats.as_dict().items())
    print(f"rtlift bench serve: stopped: {stats}", file=sys.stderr, flush=True)
    if device.error is not None:
        print(f"rtlift bench serve: device failed: {device.error}", file=sys.stderr)
        return 1
    return 0
