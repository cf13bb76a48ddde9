"""Protocol version 2 on the host side (PROTOCOL.md "Version 2"): version-1 and version-2
samples in one stream, the command packet and the CAN CMD frame, ``cmd_seq`` arithmetic, and
the command counters of a link (in-process transports: pyserial ``loop://``, python-can
``virtual``)."""

from __future__ import annotations

import struct
from binascii import crc_hqx

import can
import numpy as np
import pytest
from cobs import cobs
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_io import open_link
from firmware_io.can_codec import (
    CMD_ID,
    CanAssembler,
    decode_command_frame,
    encode_command_frame,
    encode_sample_frames,
    load_dbc,
)
from firmware_io.commands import Command, CommandTracker, is_newer, next_cmd_seq
from firmware_io.latency import LatencyRecorder
from firmware_io.samples import STATUS_HOST_CONTROL, STATUS_WATCHDOG, Counters, Sample
from firmware_io.serial_codec import (
    COMMAND_PACKET_LEN,
    SAMPLE_PACKET_LEN_V2,
    decode_command,
    encode_command,
    encode_sample,
)
from hil_sim.devices.serial_daq import cobs_data_positions
from tests.test_io_serial_codec import decode_cut as decode

COUNTS = (1_000_000, -2_000_000, 35_000_000, 250_000_000, -1, 2**31 - 1)


def v2_frame(seq: int, cmd_seq: int | None, status: int = 0x09, volt_cv: int = 6000) -> bytes:
    return encode_sample(seq, seq * 2500, volt_cv, COUNTS, status, 4321, cmd_seq)


# -- serial samples, version 2 ------------------------------------------------------------------
def test_version_2_sample_packet_layout_matches_protocol_table():
    pkt = cobs.decode(v2_frame(0x1234, 0xBEEF, status=0x19)[:-1])
    assert len(pkt) == SAMPLE_PACKET_LEN_V2 == 41 and pkt[0] == 2 and pkt[1] == 1
    assert pkt[34] == 0x19 and struct.unpack_from("<H", pkt, 35)[0] == 4321
    assert struct.unpack_from("<H", pkt, 37)[0] == 0xBEEF
    assert struct.unpack_from("<H", pkt, 39)[0] == crc_hqx(pkt[:39], 0xFFFF)


def test_version_2_sample_carries_cmd_seq_and_version_1_reads_as_zero():
    dec, out = decode(b"\x00" + v2_frame(1, None) + v2_frame(2, 700) + v2_frame(3, None))
    assert [(s.seq, s.cmd_seq) for s in out] == [(1, 0), (2, 700), (3, 0)]
    assert out[1].ft == out[0].ft and out[1].envelope_cv == 4321
    assert (dec.counters.received, dec.counters.crc_errors, dec.counters.commands_applied) == (3, 0, 1)


def test_a_version_2_header_on_a_version_1_length_is_invalid():
    body = cobs.decode(v2_frame(1, None)[:-1])[:-2]
    bad = b"\x02" + body[1:]
    dec, out = decode(b"\x00" + cobs.encode(bad + struct.pack("<H", crc_hqx(bad, 0xFFFF))) + b"\x00"
                      + v2_frame(2, 5))
    assert [s.seq for s in out] == [2] and dec.counters.crc_errors == 1


def test_a_command_packet_on_the_host_side_is_an_invalid_packet():
    dec, out = decode(b"\x00" + encode_command(1, 100) + v2_frame(1, None))
    assert len(out) == 1 and dec.counters.crc_errors == 1


def test_commands_applied_counts_distinct_echoed_cmd_seq_and_watchdog_trips_the_edges():
    wd, hc = STATUS_WATCHDOG, STATUS_HOST_CONTROL
    plan = [(None, 1), (None, wd), (3, hc), (3, hc), (4, hc), (4, wd), (4, wd), (5, hc), (5, wd), (None, 1)]
    dec, out = decode(b"\x00" + b"".join(v2_frame(i, c, s) for i, (c, s) in enumerate(plan)))
    assert len(out) == len(plan)
    assert dec.counters.commands_applied == 3 and dec.counters.watchdog_trips == 3


def test_the_first_sample_with_the_watchdog_bit_is_not_a_trip():
    dec, _ = decode(b"\x00" + v2_frame(1, 9, STATUS_WATCHDOG) + v2_frame(2, 9, STATUS_WATCHDOG))
    assert dec.counters.watchdog_trips == 0


def test_a_stream_restart_does_not_count_the_same_echo_again():
    dec, _ = decode(v2_frame(1, 9) + v2_frame(2, 9))
    dec.restart()
    dec.feed(v2_frame(800, 9) + v2_frame(801, 10))
    assert dec.counters.commands_applied == 2 and dec.counters.lost == 0


MIXED = st.lists(st.tuples(st.sampled_from(["v1", "v2", "drop", "corrupt"]), st.integers(0, 65535),
                           st.sampled_from([0, STATUS_HOST_CONTROL, STATUS_WATCHDOG]), st.integers(0, 10_000)),
                 min_size=1, max_size=60)


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 65535), MIXED, st.lists(st.integers(1, 100), max_size=10))
def test_a_mixed_version_1_and_2_stream_decodes_exactly(seq0, plan, cuts):
    stream = bytearray(b"\x00")
    sent: list[tuple[int, int, int, int]] = []
    crc_errors = 0
    for i, (op, cmd_seq, status, pick) in enumerate(plan):
        seq = (seq0 + i) & 0xFFFF
        f = v2_frame(seq, cmd_seq if op == "v2" else None, status, volt_cv=i)
        if op == "drop":
            continue
        if op == "corrupt":
            pos = cobs_data_positions(f)[pick % len(cobs_data_positions(f))]
            stream += f[:pos] + bytes((1 + (f[pos] + pick % 254) % 255,)) + f[pos + 1:]
            crc_errors += 1
            continue
        stream += f
        sent.append((seq, i, status, cmd_seq if op == "v2" else 0))
    dec, out = decode(bytes(stream), cuts)
    assert [(s.seq, s.volt_cv, s.status, s.cmd_seq) for s in out] == sent
    applied, last, trips, prev = 0, 0, 0, None
    for _, _, status, cmd_seq in sent:
        if cmd_seq and cmd_seq != last:
            applied, last = applied + 1, cmd_seq
        trips += bool(status & STATUS_WATCHDOG) and prev is False
        prev = bool(status & STATUS_WATCHDOG)
    idx = [i for _, i, _, _ in sent]
    c = dec.counters
    assert (c.received, c.lost, c.crc_errors, c.commands_applied, c.watchdog_trips) == (
        len(sent), idx[-1] - idx[0] + 1 - len(idx) if idx else 0, crc_errors, applied, trips)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.one_of(st.binary(max_size=50), st.integers(0, 65535).map(lambda c: v2_frame(c, c))),
                max_size=20), st.lists(st.integers(1, 64), max_size=10))
def test_decoder_never_raises_on_random_bytes_mixed_with_version_2_packets(parts, cuts):
    dec, out = decode(b"".join(parts), cuts)
    c = dec.counters
    assert c.received == len(out) and c.commands_applied <= c.received


# -- the serial command packet ------------------------------------------------------------------
def test_command_packet_layout_matches_protocol_table():
    pkt = cobs.decode(encode_command(0xABCD, 19_000, 125, True, 50)[:-1])
    assert len(pkt) == COMMAND_PACKET_LEN == 12
    assert struct.unpack("<BBHHHBBH", pkt) == (2, 3, 0xABCD, 19_000, 125, 1, 50, crc_hqx(pkt[:10], 0xFFFF))
    assert encode_command(1, 0).endswith(b"\x00") and encode_command(1, 0).count(0) == 1


COMMANDS = st.builds(Command, st.integers(1, 65535), st.integers(0, 65535), st.integers(0, 65535),
                     st.booleans(), st.integers(0, 255))


@settings(max_examples=300, deadline=None)
@given(COMMANDS)
def test_serial_command_round_trips(cmd):
    wire = encode_command(cmd.cmd_seq, cmd.envelope_cv, cmd.burst_period_ms, cmd.enable, cmd.watchdog_ms_div10)
    assert decode_command(wire[:-1]) == cmd


def test_every_single_byte_corruption_of_a_command_is_rejected():
    good = encode_command(513, 6000, 125, True, 50)
    rejected = 0
    for pos in cobs_data_positions(good):
        for new in range(1, 256):
            if new != good[pos]:
                assert decode_command(good[:pos] + bytes((new,)) + good[pos + 1:-1]) is None
                rejected += 1
    assert rejected == 254 * len(cobs_data_positions(good))


def test_commands_of_a_wrong_length_version_kind_or_cmd_seq_zero_are_rejected():
    def packet(body: bytes) -> bytes:
        return cobs.encode(body + struct.pack("<H", crc_hqx(body, 0xFFFF)))

    body = struct.pack("<BBHHHBB", 2, 3, 7, 100, 0, 1, 0)
    assert decode_command(packet(body)) == Command(7, 100)
    for bad in (body[:-1], body + b"\x00", b"\x01" + body[1:], b"\x02\x01" + body[2:],
                struct.pack("<BBHHHBB", 2, 3, 0, 100, 0, 1, 0)):
        assert decode_command(packet(bad)) is None
    assert decode_command(b"") is None and decode_command(b"\x05\x01") is None


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=40))
def test_decode_command_never_raises(data):
    decode_command(data)
    decode_command_frame(data)


@pytest.mark.parametrize("args,field", [((0, 100), "cmd_seq"), ((65536, 100), "cmd_seq"), ((1, -1), "envelope_cv"),
                                        ((1, 65536), "envelope_cv"), ((1, 1, 70000), "burst_period_ms"),
                                        ((1, 1, 0, True, 256), "watchdog_ms_div10"), ((1, 1.5), "envelope_cv"),
                                        ((1, 1, 0, 1), "enable")])
def test_out_of_range_command_values_are_one_line_value_errors(args, field):
    with pytest.raises(ValueError) as info:
        encode_command(*args)
    assert "\n" not in str(info.value) and field in str(info.value)


# -- CAN CMD ------------------------------------------------------------------------------------
def test_can_cmd_frame_is_little_endian_at_the_protocol_offsets():
    fid, data = encode_command_frame(200, 19_000, 125, False, 50)
    assert fid == CMD_ID == 0x100 and struct.unpack("<BHHBBB", data) == (200, 19_000, 125, 0, 50, 0)


@settings(max_examples=200, deadline=None)
@given(COMMANDS.filter(lambda c: c.cmd_seq < 256))
def test_can_command_round_trips_through_cantools(cmd):
    _, data = encode_command_frame(cmd.cmd_seq, cmd.envelope_cv, cmd.burst_period_ms, cmd.enable,
                                   cmd.watchdog_ms_div10)
    assert decode_command_frame(data) == cmd
    phys = load_dbc().decode_message(CMD_ID, data)  # the DBC's physical units
    assert phys["envelope_cv"] == pytest.approx(cmd.envelope_cv / 100)
    assert phys["burst_period_ms"] == cmd.burst_period_ms
    assert phys["watchdog_ms_div10"] == 10 * cmd.watchdog_ms_div10


@pytest.mark.parametrize("cmd_seq", [0, 256, -1])
def test_can_cmd_seq_is_a_nonzero_u8(cmd_seq):
    with pytest.raises(ValueError, match="cmd_seq must be an integer in 1..255"):
        encode_command_frame(cmd_seq, 100)


def test_can_cmd_frames_of_a_wrong_length_or_cmd_seq_zero_are_rejected():
    _, data = encode_command_frame(5, 100)
    assert decode_command_frame(data[:7]) is None and decode_command_frame(b"\x00" + data[1:]) is None


def test_the_assembler_reads_cmd_seq_from_ft_force_and_status_bits_4_and_5():
    asm = CanAssembler()
    out = []
    for seq, cmd_seq, status in [(1, 0, 1), (2, 200, STATUS_HOST_CONTROL), (3, 200, STATUS_WATCHDOG), (4, 201, 0)]:
        for fid, data in encode_sample_frames(seq, seq, 0, 0, status, (1, 2, 3), (4, 5, 6), cmd_seq=cmd_seq):
            s = asm.feed(fid, data)
        out.append(s)
    assert [(s.cmd_seq, s.status) for s in out] == [(0, 1), (200, 16), (200, 32), (201, 0)]
    assert (asm.counters.commands_applied, asm.counters.watchdog_trips, asm.counters.received) == (2, 1, 4)


# -- cmd_seq arithmetic, latency, tracker -------------------------------------------------------
@pytest.mark.parametrize("modulus", [256, 65536])
def test_cmd_seq_wraps_and_is_never_zero(modulus):
    seqs = [0]
    for _ in range(2 * modulus + 3):
        seqs.append(next_cmd_seq(seqs[-1], modulus))
    assert 0 not in seqs[1:] and max(seqs) == modulus - 1 and seqs[modulus - 1:modulus + 1] == [modulus - 1, 1]
    assert all(is_newer(b, a, modulus) for a, b in zip(seqs[1:-1], seqs[2:], strict=True))


def test_newer_means_ahead_by_less_than_half_the_modulus():
    assert is_newer(1, None, 65536) and is_newer(40000, None, 65536)
    assert is_newer(2, 65535, 65536) and not is_newer(5, 5, 65536) and not is_newer(4, 5, 65536)
    assert is_newer(5 + 32767, 5, 65536) and not is_newer(5 + 32768, 5, 65536)
    assert is_newer(1, 255, 256) and not is_newer(200, 10, 256)


def test_latency_percentiles_are_within_half_a_percent_in_fixed_memory():
    rng = np.random.default_rng(3)
    x = rng.lognormal(np.log(2e-3), 0.5, 20_000)
    rec = LatencyRecorder()
    size = len(rec.counts)
    for v in x:
        rec.append(float(v))
    assert len(rec.counts) == size and rec.n == x.size
    for q in (50, 90, 99):
        assert rec.percentile(q) == pytest.approx(np.percentile(x, q, method="inverted_cdf"), rel=0.006)
    assert LatencyRecorder().percentile(50) is None


def test_tracker_times_each_command_to_its_first_echo_and_skips_superseded_ones():
    counters = Counters()
    tr = CommandTracker(counters, 65536)
    for t in (0.0, 0.001):
        tr.sent(tr.next_seq(), t)  # 1 superseded by 2 before any echo
    for t, echo in [(0.004, 0), (0.005, 2), (0.0075, 2)]:
        tr.received(Sample(0, 0, 0, 0, (0.0,) * 6, 0, t, echo))
    assert counters.commands_sent == 2 and counters.command_latency.n == 1
    assert counters.command_latency.percentile(50) == pytest.approx(0.004, rel=0.006)

@pytest.mark.parametrize("modulus", [65536, 256])
def test_a_new_host_numbers_its_commands_after_the_last_one_the_device_applied(modulus):
    """A device that remembers the previous session's cmd_seq (49, or 255 on the wrap) applies
    this host's first command: it is newer under PROTOCOL.md's rule."""
    for remembered in (49, modulus - 1):
        tr = CommandTracker(Counters(), modulus)
        tr.received(Sample(0, 0, 0, 0, (0.0,) * 6, 0, 0.0, remembered))
        first = tr.next_seq()
        assert is_newer(first, remembered, modulus) and first != 0
        tr.sent(first, 0.001)
        tr.received(Sample(1, 0, 0, 0, (0.0,) * 6, 0, 0.002, remembered))   # not yet applied: no rebase
        assert tr.next_seq() == next_cmd_seq(first, modulus)



# -- links --------------------------------------------------------------------------------------
def test_serial_link_writes_the_command_packet_and_counts_it():
    with open_link({"kind": "serial", "port": "loop://"}) as link:
        assert link.send_command(6000, 125, watchdog_ms_div10=20) == 1
        assert link.send_command(0, enable=False) == 2
        wire = link._ser.read(100)
        assert wire == encode_command(1, 6000, 125, True, 20) + encode_command(2, 0, 0, False, 0)
        assert link.counters.commands_sent == 2


def test_a_bad_command_value_sends_and_counts_nothing():
    with open_link({"kind": "serial", "port": "loop://"}) as link:
        with pytest.raises(ValueError):
            link.send_command(70_000)
        assert link._ser.in_waiting == 0 and link.counters.commands_sent == 0
        assert link.send_command(1) == 1  # the failed one used no cmd_seq


def test_can_link_sends_the_cmd_frame_on_the_bus_and_times_the_echo():
    config = {"kind": "can", "interface": "virtual", "channel": "test_io_commands_cmd"}
    with open_link(config) as link, can.Bus(interface="virtual", channel=config["channel"],
                                            ignore_config=True) as device:
        assert [link.send_command(100 * k) for k in range(1, 4)] == [1, 2, 3]
        got = [device.recv(1.0) for _ in range(3)]
        assert [(m.arbitration_id, decode_command_frame(m.data)) for m in got] == [
            (0x100, Command(k, 100 * k)) for k in range(1, 4)]
        for seq, echo in enumerate((0, 3, 3)):
            for fid, data in encode_sample_frames(seq, seq, 0, 0, 1, (1, 2, 3), (4, 5, 6), cmd_seq=echo):
                device.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False))
        assert [link.recv(1.0).cmd_seq for _ in range(3)] == [0, 3, 3]
        c = link.counters.as_dict()
        lat = link.counters.command_latency_ms()
        assert (c["commands_sent"], c["commands_applied"]) == (3, 1)
        assert 0 < lat["command_latency_p50_ms"] == lat["command_latency_p99_ms"]


def test_as_dict_stays_exact_integers_and_latency_is_apart():
    c = Counters()
    assert all(type(v) is int for v in c.as_dict().values()) and "command_latency" not in c.as_dict()
    assert c.command_latency_ms() == {"command_latency_p50_ms": None, "command_latency_p99_ms": None}
    c.command_latency.append(0.002)
    assert c.command_latency_ms()["command_latency_p99_ms"] == pytest.approx(2.0, rel=0.006)


def test_can_link_cmd_seq_wraps_at_256_and_skips_zero():
    with open_link({"kind": "can", "interface": "virtual", "channel": "test_io_commands_wrap"}) as link:
        seqs = [link.send_command(0) for _ in range(300)]
    assert seqs[254:257] == [255, 1, 2] and 0 not in seqs


def test_a_closed_link_refuses_to_send():
    from firmware_io import LinkError

    link = open_link({"kind": "serial", "port": "loop://"})
    link.close()
    with pytest.raises(LinkError, match="closed"):
        link.send_command(100)
