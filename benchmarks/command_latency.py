"""Where the command latency goes, per link: send → device receipt → echo written → host receipt.

The bench as in ``benchmarks/control_loop.py`` (a :class:`hil_sim.hil.HilStream` on a pty, in
this process) and a host in its own process that reads every sample through
``firmware_io.open_link`` (serial: pyserial; slcan: python-can's real ``slcan`` driver) and
sends a command 10 samples before each 50-sample burst period, as ``rtlift control`` does.
Both ends stamp ``time.perf_counter`` (CLOCK_MONOTONIC, one clock for both processes); the
device's stamps come from wrappers around this device instance's command receipt and
``_emit``. Per command, in ms:

- ``total``: the host's send → its receipt of the first sample echoing the command (what
  ``command_latency`` measures);
- ``send_call``: the host's ``send_command`` call itself;
- ``send_to_device``: send → the device firmware gets the command;
- ``device_to_echo``: the device gets it → it starts emitting the echoing sample (the wait for
  the next sample of its clock, by the protocol, plus any lateness of the device thread);
- ``echo_to_host``: the echoing sample written to the pty → the host has it decoded;

and per sample: the host process's CPU time (µs), the device's ``_emit`` duration (ms).
``total`` = ``send_to_device`` + ``device_to_echo`` + the emit + ``echo_to_host``.
Prints one JSON line: ``links`` → link → ``commands``, ``lost``, each stage's ``p50``/``p99``/
``max``, ``host_cpu_us_per_sample``. ``--link serial|slcan|both`` (default both), ``--seconds``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks._common import emit  # noqa: E402

COMMAND_EVERY = 50
COMMAND_AT = 40
"""A command after the 40th sample of every 50 (10 samples before the next burst onset)."""
STAGES = ("total", "send_call", "send_to_device", "device_to_echo", "echo_to_host")


def host(kind: str, path: str, seconds: float, out: str) -> None:
    """The host process: read every sample, send commands, stamp them; JSON to ``out``."""
    from firmware_io import open_link

    config = ({"kind": "serial", "port": path} if kind == "serial" else
              {"kind": "can", "interface": "slcan", "channel": path, "bitrate": 500000})
    pc = time.perf_counter
    sent: dict[int, list[float]] = {}
    echoed: dict[int, float] = {}
    n = 0
    end = None
    with open_link(config) as link:
        print("link open", file=sys.stderr, flush=True)
        cpu0 = resource.getrusage(resource.RUSAGE_SELF)
        while end is None or pc() < end:
            s = link.recv(0.25)
            if s is None:
                continue
            now = pc()
            end = end or now + seconds
            n += 1
            if s.cmd_seq and s.cmd_seq not in echoed:
                echoed[s.cmd_seq] = now
            if n % COMMAND_EVERY == COMMAND_AT:
                t0 = pc()
                seq = link.send_command(1000 + 100 * (n // COMMAND_EVERY % 50))
                sent[seq] = [t0, pc()]
                echoed.pop(seq, None)  # a cmd_seq reused after wrapping counts from now
        cpu1 = resource.getrusage(resource.RUSAGE_SELF)
        lost = link.counters.lost
    cpu = (cpu1.ru_utime + cpu1.ru_stime) - (cpu0.ru_utime + cpu0.ru_stime)
    with open(out, "w", encoding="utf-8") as f:
        json.dump({"sent": sent, "echoed": echoed, "samples": n, "cpu_s": cpu, "lost": lost}, f)


def _stats(values_ms: list[float]) -> dict[str, float]:
    a = np.asarray(values_ms)
    return {"p50": float(np.median(a)), "p99": float(np.percentile(a, 99)), "max": float(a.max())}


def one_link(kind: str, seconds: float, tmp: str) -> dict:
    from hil_sim.devices import SerialDaq, SlcanAdapter
    from hil_sim.hil import HilStream
    from rtlift.app.hil_tracking import FADE

    pc = time.perf_counter
    stream = HilStream("random", seed=11, effects=[FADE])
    dev = (SlcanAdapter if kind == "slcan" else SerialDaq)(stream)
    stream.control = ctl = dev.control
    received: dict[int, float] = {}
    first_echo: dict[int, tuple[float, float]] = {}
    emits: list[float] = []
    receive, emit_sample = ctl.receive, dev._emit

    def timed_receive(command, index):
        if command is not None:
            received.setdefault(command.cmd_seq, pc())
        receive(command, index)

    def timed_emit(index, sample):
        t0 = pc()
        emit_sample(index, sample)
        t1 = pc()
        emits.append(t1 - t0)
        applied = ctl.applied
        if applied is not None and applied.cmd_seq not in first_echo:
            first_echo[applied.cmd_seq] = (t0, t1)

    ctl.receive, dev._emit = timed_receive, timed_emit
    out = os.path.join(tmp, f"host_{kind}.json")
    proc = subprocess.Popen([sys.executable, "-m", "benchmarks.command_latency", "--host", kind, dev.path,
                             str(seconds), out], stderr=subprocess.PIPE, text=True,
                            cwd=os.path.join(os.path.dirname(__file__), ".."))
    line = proc.stderr.readline()
    if "link open" not in line:
        dev.stop()
        raise RuntimeError(f"host did not start: {line.strip()}")
    with dev:
        dev.start()
        proc.wait(seconds + 60)
    with open(out, encoding="utf-8") as f:
        h = json.load(f)
    rows = {s: [] for s in STAGES}
    for key, (t_send, t_sent) in h["sent"].items():
        seq = int(key)
        t_back = h["echoed"].get(key)
        if t_back is None or seq not in received or seq not in first_echo:
            continue  # the last command, sent as the host stopped
        t_dev = received[seq]
        e0, e1 = first_echo[seq]
        for stage, v in zip(STAGES, (t_back - t_send, t_sent - t_send, t_dev - t_send, e0 - t_dev,
                                     t_back - e1), strict=True):
            rows[stage].append(1e3 * v)
    return {"commands": len(rows["total"]), "lost": h["lost"], "samples": h["samples"],
            **{s: _stats(v) for s, v in rows.items()},
            "device_emit_ms": _stats([1e3 * v for v in emits]),
            "host_cpu_us_per_sample": 1e6 * h["cpu_s"] / max(1, h["samples"])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--link", choices=("serial", "slcan", "both"), default="both")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--host", nargs=4, metavar=("KIND", "PATH", "SECONDS", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.host:
        kind, path, seconds, out = args.host
        host(kind, path, float(seconds), out)
        return
    links = ("serial", "slcan") if args.link == "both" else (args.link,)
    result = {}
    with tempfile.TemporaryDirectory() as tmp:
        for kind in links:
            r = result[kind] = one_link(kind, args.seconds, tmp)
            print(f"{kind}: {r['commands']} commands, lost {r['lost']}, host CPU "
                  f"{r['host_cpu_us_per_sample']:.0f} us/sample, device emit p50 {r['device_emit_ms']['p50']:.3f} ms")
            for s in STAGES:
                print(f"  {s:15} p50 {r[s]['p50']:6.3f}  p99 {r[s]['p99']:6.3f}  max {r[s]['max']:6.3f} ms")
    load = os.getloadavg()[0]
    emit({"links": result, "seconds": args.seconds, "load_average_1min": load})


if __name__ == "__main__":
    main()
