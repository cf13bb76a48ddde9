"""Protocol version 2 over real pseudo-terminals: the host sends commands through pyserial and
through python-can's real ``slcan`` driver; the emulated devices apply them, echo ``cmd_seq``,
count bad commands and run the watchdog. The devices' statistics are the oracle; timing is
only bounded generously (a shared 2-core machine)."""

from __future__ import annotations

import time
from contextlib import contextmanager

import can
import pytest
from cobs import cobs

from firmware_io import open_link
from firmware_io.commands import ENVELOPE_LIMIT_CV
from firmware_io.samples import STATUS_HOST_CONTROL, STATUS_WATCHDOG
from firmware_io.serial_codec import encode_command
from hil_sim.devices import SerialDaq, SlcanAdapter
from hil_sim.experiments import daq_stream
from rtlift.core.rate import FS_HZ

pytestmark = pytest.mark.pty

FS = int(FS_HZ)
GENEROUS_S = 3.0
"""Longest wait for something the device does within a few samples."""


def serial_config(dev):
    return {"kind": "serial", "port": dev.path}


def can_config(dev):
    return {"kind": "can", "interface": "slcan", "channel": dev.path, "bitrate": 500000}


DEVICES = [(SerialDaq, serial_config), (SlcanAdapter, can_config)]
IDS = ["serial", "slcan"]


@contextmanager
def streaming(make, config, seed: int, **extra):
    """(device, link): a ``make`` device streaming the static experiment (``seed``), started, and
    the link ``config`` (with ``extra``) opens to it; both closed on the way out."""
    dev = make(daq_stream("static", seed=seed))
    with dev, open_link({**config(dev), **extra}) as link:
        dev.start()
        yield dev, link


def read_until(link, done, timeout_s=GENEROUS_S):
    """Samples until ``done(sample)`` (that one included); fails after ``timeout_s``."""
    out = []
    end = time.perf_counter() + timeout_s
    while time.perf_counter() < end:
        s = link.recv(0.1)
        if s is None:
            continue
        out.append(s)
        if done(s):
            return out
    raise AssertionError(f"not seen within {timeout_s} s (last: {out[-1] if out else None})")


def read_for(link, n):
    """The next ``n`` samples (fails if they take far longer than ``n`` periods)."""
    out = []
    end = time.perf_counter() + n / FS + GENEROUS_S
    while len(out) < n and time.perf_counter() < end:
        s = link.recv(0.1)
        if s is not None:
            out.append(s)
    assert len(out) == n, f"{len(out)} of {n} samples"
    return out


@pytest.mark.parametrize("make,config", DEVICES, ids=IDS)
def test_commands_are_echoed_and_counted_exactly(make, config):
    with streaming(make, config, 1) as (dev, link):
        before = read_for(link, 40)
        sent = []
        for k in range(1, 41):
            env = 500 * k
            cmd_seq = link.send_command(env, watchdog_ms_div10=200)
            sent.append(cmd_seq)
            echoed = read_until(link, lambda s, c=cmd_seq: s.cmd_seq == c)
            last = echoed[-1]
            assert last.envelope_cv == min(env, ENVELOPE_LIMIT_CV) and last.status & STATUS_HOST_CONTROL
            assert all(s.cmd_seq in (cmd_seq, sent[-2] if k > 1 else 0) for s in echoed)
        more = read_for(link, 20)
        c = link.counters.as_dict()
        lat = link.counters.command_latency_ms()
    assert all(s.cmd_seq == 0 and not s.status & (STATUS_HOST_CONTROL | STATUS_WATCHDOG) for s in before)
    assert all(s.cmd_seq == 40 for s in more)
    assert sent == list(range(1, 41))
    st = dev.stats
    assert c["commands_sent"] == st.commands_valid == st.commands_applied == c["commands_applied"] == 40
    assert st.cmd_errors == st.commands_ignored == st.commands_superseded == 0
    assert c["watchdog_trips"] == st.watchdog_trips == 0
    assert (c["lost"], c["crc_errors"], c["duplicates"]) == (0, 0, 0)
    assert 0 < lat["command_latency_p50_ms"] <= lat["command_latency_p99_ms"]  # size: benchmarks/command_latency.py
    assert dev.control.applied.cmd_seq == 40 and dev.control.envelope_cv == ENVELOPE_LIMIT_CV
    assert dev.error is None


@pytest.mark.parametrize("make,config", DEVICES, ids=IDS)
def test_commands_faster_than_samples_are_applied_or_superseded_exactly(make, config):
    with streaming(make, config, 6) as (dev, link):
        read_for(link, 10)
        for k in range(300):
            link.send_command(k, watchdog_ms_div10=200)
            if k % 7 == 0:
                link.recv(0.1)
        last = link._commands.last_sent
        read_until(link, lambda s: s.cmd_seq == last)
        read_for(link, 10)
        c = link.counters.as_dict()
    st = dev.stats
    assert st.commands_superseded > 0 and st.cmd_errors == st.commands_ignored == 0
    assert c["commands_sent"] == 300 == st.commands_valid == st.commands_applied + st.commands_superseded
    assert c["commands_applied"] == st.commands_applied
    assert (c["lost"], c["crc_errors"]) == (0, 0)


def test_serial_device_streams_version_1_until_the_first_command(tmp_path):
    log = tmp_path / "raw.bin"
    with streaming(SerialDaq, serial_config, 2, log=str(log)) as (dev, link):
        read_for(link, 30)
        cmd_seq = link.send_command(3000)
        read_until(link, lambda s: s.cmd_seq == cmd_seq)
        read_for(link, 10)
        received = link.counters.received
    versions = [cobs.decode(p)[0] for p in log.read_bytes().split(b"\x00") if p]
    assert len(versions) == received and versions[0] == 1 and versions[-1] == 2
    first_v2 = versions.index(2)
    assert set(versions[:first_v2]) == {1} and set(versions[first_v2:]) == {2} and first_v2 >= 30


@pytest.mark.parametrize("make,config", DEVICES, ids=IDS)
def test_a_corrupted_command_is_counted_by_the_device_and_not_applied(make, config):
    with streaming(make, config, 3) as (dev, link):
        read_for(link, 10)
        if make is SerialDaq:
            good = encode_command(1, 7000)
            link._ser.write(good[:3] + bytes((good[3] ^ 0x10,)) + good[4:])  # one byte changed: bad CRC
        else:
            link._bus.send(can.Message(arbitration_id=0x100, data=b"\x01\x58\x1b\x00\x00\x01\x00",
                                       is_extended_id=False))  # DLC 7
        cmd_seq = link.send_command(6000)
        applied = read_until(link, lambda s: s.cmd_seq == cmd_seq)[-1]
        if make is SerialDaq:  # reported once a second while nonzero
            read_until(link, lambda s: "cmd_errors=1" in link.events, timeout_s=1.5 + GENEROUS_S)
        c = link.counters.as_dict()
    assert dev.stats.cmd_errors == 1 and dev.stats.commands_applied == 1
    assert c["commands_sent"] == c["commands_applied"] == 1 and applied.envelope_cv == 6000


@pytest.mark.parametrize("make,config", DEVICES, ids=IDS)
def test_a_command_that_is_not_newer_is_ignored(make, config):
    with streaming(make, config, 4) as (dev, link):
        for _ in range(3):
            cmd_seq = link.send_command(1000 * link._commands.next_seq())
        read_until(link, lambda s: s.cmd_seq == cmd_seq)
        if make is SerialDaq:
            link._ser.write(encode_command(2, 9999))
        else:
            link._bus.send(can.Message(arbitration_id=0x100, data=b"\x02\x0f\x27\x00\x00\x01\x00\x00",
                                       is_extended_id=False))
        after = read_for(link, 40)
    assert dev.stats.commands_ignored == 1 and dev.stats.cmd_errors == 0
    assert all(s.cmd_seq == 3 and s.envelope_cv == 3000 for s in after)


@pytest.mark.parametrize("make,config", DEVICES, ids=IDS)
def test_silence_trips_the_watchdog_and_the_next_command_takes_control_again(make, config):
    with streaming(make, config, 5) as (dev, link):
        first = link.send_command(8000, watchdog_ms_div10=10)  # 100 ms
        applied = read_until(link, lambda s: s.cmd_seq == first)[-1]
        tripped = read_until(link, lambda s: s.status & STATUS_WATCHDOG)
        wd = tripped[-1]
        # the silence in the device's own clock (its samples): the host's clock is not the device's,
        # and a device catching up after a stall sends 100 ms of samples in less
        silence_samples = (wd.seq - applied.seq) % 256
        assert not wd.status & STATUS_HOST_CONTROL and wd.envelope_cv == 8000 and wd.cmd_seq == first
        ramp = [wd, *read_for(link, 40)]  # the 100 ms ramp: 200 cV less per sample, 0 after 40
        assert not dev.control.enabled and dev.control.envelope_cv == 0
        still = read_for(link, 20)
        again = link.send_command(4000)
        back = read_until(link, lambda s: s.cmd_seq == again)[-1]
        c = link.counters.as_dict()
    assert 0.1 * FS_HZ - 1 <= silence_samples <= 0.1 * FS_HZ + 1     # it tripped at its 100 ms
    assert [s.envelope_cv for s in ramp] == [8000 - 200 * j for j in range(41)]
    assert [(s.seq - wd.seq) % 256 for s in ramp] == list(range(41))
    assert all(s.status & STATUS_WATCHDOG and s.envelope_cv == 0 for s in ramp[-1:] + still)
    assert back.status & STATUS_HOST_CONTROL and not back.status & STATUS_WATCHDOG and back.envelope_cv == 4000
    assert c["watchdog_trips"] == dev.stats.watchdog_trips == 1
    assert c["commands_sent"] == c["commands_applied"] == 2
