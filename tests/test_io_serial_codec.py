"""Serial wire format (PROTOCOL.md "Serial link"): COBS + CRC-16/CCITT-FALSE packets and the
decoder's exact counters, including property tests over arbitrary bytes."""

from __future__ import annotations

import struct
from binascii import crc_hqx

from cobs import cobs
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_io.samples import Sample
from firmware_io.serial_codec import SAMPLE_PACKET_LEN, SerialDecoder, encode_event, encode_sample
from hil_sim.devices.serial_daq import cobs_data_positions, invalid_chunks

COUNTS = (1_000_000, -2_000_000, 35_000_000, 250_000_000, -1, 2**31 - 1)


def decode(stream: bytes, pieces: int = 1):
    out = []
    dec = SerialDecoder(out.append)
    step = max(1, len(stream) // pieces)
    for i in range(0, len(stream), step):
        dec.feed(stream[i:i + step])
    return dec, out


def decode_cut(stream: bytes, cuts: list[int] = ()) -> tuple[SerialDecoder, list[Sample]]:
    """The decoder and the samples it gave, ``stream`` fed in pieces of the lengths ``cuts`` (then the rest)."""
    out: list[Sample] = []
    dec = SerialDecoder(out.append)
    pos = 0
    for n in cuts:
        dec.feed(stream[pos:pos + n])
        pos += n
    dec.feed(stream[pos:])
    return dec, out


def frame(seq: int, **kw) -> bytes:
    fields = {"t_us": seq * 2500, "volt_cv": 6000, "counts": COUNTS, "status": 0x09, "envelope_cv": 6000}
    fields.update(kw)
    return encode_sample(seq, fields["t_us"], fields["volt_cv"], fields["counts"], fields["status"],
                         fields["envelope_cv"])


def test_crc_is_ccitt_false_check_value():
    assert crc_hqx(b"123456789", 0xFFFF) == 0x29B1


def test_sample_packet_layout_matches_protocol_table():
    pkt = cobs.decode(frame(0x1234, t_us=0xDEADBEEF, volt_cv=-123, status=0x0B, envelope_cv=4321)[:-1])
    assert len(pkt) == SAMPLE_PACKET_LEN == 39
    assert pkt[0] == 1 and pkt[1] == 1
    assert struct.unpack_from("<H", pkt, 2)[0] == 0x1234
    assert struct.unpack_from("<I", pkt, 4)[0] == 0xDEADBEEF
    assert struct.unpack_from("<h", pkt, 8)[0] == -123
    assert struct.unpack_from("<6i", pkt, 10) == COUNTS
    assert pkt[34] == 0x0B
    assert struct.unpack_from("<H", pkt, 35)[0] == 4321
    assert struct.unpack_from("<H", pkt, 37)[0] == crc_hqx(pkt[:37], 0xFFFF)


def test_decoded_sample_scales_counts_by_counts_per_unit():
    dec, out = decode(b"\x00" + frame(7, volt_cv=-5, envelope_cv=9, status=4))
    (s,) = out
    assert (s.seq, s.t_us, s.volt_cv, s.envelope_cv, s.status) == (7, 17500, -5, 9, 4)
    assert s.ft == (1.0, -2.0, 35.0, 0.25, -1e-9, (2**31 - 1) / 1e9)


def test_bytes_before_the_first_delimiter_are_one_resync_not_a_crc_error():
    dec, out = decode(frame(1)[10:] + frame(2) + frame(3))
    assert [s.seq for s in out] == [2, 3]
    assert dec.counters.crc_errors == 0 and dec.counters.resyncs == 1 and dec.counters.lost == 0


def test_a_complete_first_packet_without_a_leading_delimiter_is_a_sample():
    dec, out = decode(frame(1) + frame(2))
    assert [s.seq for s in out] == [1, 2]
    assert (dec.counters.received, dec.counters.resyncs, dec.counters.crc_errors) == (2, 0, 0)
    dec, out = decode(frame(1)[1:] + frame(2))  # one byte short: fails its CRC, a resync
    assert [s.seq for s in out] == [2] and (dec.counters.resyncs, dec.counters.crc_errors) == (1, 0)


def test_restart_forgets_the_stream_but_keeps_the_counters():
    dec, out = decode(frame(1) + frame(2) + frame(3)[:7])
    dec.restart()
    dec.feed(frame(500) + frame(501))
    assert [s.seq for s in out] == [1, 2, 500, 501] and dec.counters.lost == 0 and dec.counters.received == 4


def test_lost_counts_the_seq_gap_across_the_u16_wrap():
    dec, out = decode(b"\x00" + frame(65534) + frame(65535) + frame(2))
    assert [s.seq for s in out] == [65534, 65535, 2]
    assert dec.counters.lost == 2 and dec.counters.received == 3


def test_repeated_seq_is_a_duplicate_not_a_sample_or_a_loss():
    dec, out = decode(b"\x00" + frame(5) + frame(5) + frame(6))
    assert [s.seq for s in out] == [5, 6]
    assert (dec.counters.duplicates, dec.counters.lost) == (1, 0)


def test_event_packets_are_counted_and_kept():
    dec, out = decode(b"\x00" + encode_event("overtemp 71°C") + frame(1))
    assert dec.counters.events == 1 and list(dec.events) == ["overtemp 71°C"] and len(out) == 1


def test_wrong_version_wrong_length_and_unknown_kind_are_invalid_packets():
    def packet(body: bytes) -> bytes:
        return cobs.encode(body + struct.pack("<H", crc_hqx(body, 0xFFFF))) + b"\x00"

    good = cobs.decode(frame(1)[:-1])[:-2]
    stream = b"\x00" + packet(b"\x03" + good[1:]) + packet(good[:-1]) + packet(b"\x01\x07" + good[2:])
    dec, out = decode(stream + frame(2))
    assert out[0].seq == 2 and dec.counters.crc_errors == 3 and dec.counters.resyncs == 1


def test_endless_garbage_without_delimiter_is_one_invalid_packet():
    dec, out = decode(b"\x00" + bytes([0x55]) * 5000 + b"\x00" + frame(1), pieces=7)
    assert dec.counters.crc_errors == 1 and [s.seq for s in out] == [1]


def test_every_single_byte_corruption_of_a_packet_body_is_detected():
    good = frame(300)
    for pos in cobs_data_positions(good):
        for new in (1, 0x7F, 0xFF):
            if new == good[pos]:
                continue
            bad = good[:pos] + bytes((new,)) + good[pos + 1:]
            dec, out = decode(b"\x00" + bad + frame(301))
            assert [s.seq for s in out] == [301] and dec.counters.crc_errors == 1


# -- properties -------------------------------------------------------------------------------
@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=600), st.lists(st.integers(1, 64), max_size=20))
def test_decoder_never_raises_on_arbitrary_bytes_in_any_chunking(data, cuts):
    dec, out = decode_cut(data, cuts)
    c = dec.counters
    assert c.received == len(out) and min(c.received, c.crc_errors, c.lost, c.resyncs) >= 0


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300), st.integers(0, 65535), st.integers(1, 20))
def test_decoder_recovers_at_the_first_frame_after_any_garbage(garbage, seq0, n):
    frames = b"".join(frame((seq0 + i) & 0xFFFF) for i in range(n))
    dec, out = decode(garbage + b"\x00" + frames, pieces=3)
    assert [s.seq for s in out] == [(seq0 + i) & 0xFFFF for i in range(n)]
    assert dec.counters.lost == 0


OPS = st.sampled_from(["ok", "ok", "ok", "drop", "dup", "corrupt"])
GARBAGE = st.one_of(st.just(b""), st.binary(min_size=1, max_size=32))


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 65535),
       st.lists(st.tuples(OPS, GARBAGE, st.integers(0, 10_000)), min_size=1, max_size=60),
       st.lists(st.integers(1, 100), max_size=10))
def test_counters_are_exact_for_any_mix_of_drops_duplicates_corruption_and_garbage(seq0, plan, cuts):
    stream = bytearray(b"\x00")
    expect = {"crc_errors": 0, "duplicates": 0, "resyncs": 0}
    delivered: list[int] = []
    in_error = False

    def invalid(n: int) -> None:
        nonlocal in_error
        if n:
            expect["crc_errors"] += n
            expect["resyncs"] += 0 if in_error else 1
            in_error = True

    for i, (op, garbage, pick) in enumerate(plan):
        if garbage:
            stream += garbage + b"\x00"
            invalid(invalid_chunks(garbage + b"\x00"))
        f = frame((seq0 + i) & 0xFFFF, volt_cv=i)
        if op == "drop":
            continue
        if op == "corrupt":
            positions = cobs_data_positions(f)
            pos = positions[pick % len(positions)]
            new = 1 + (f[pos] + pick % 254) % 255  # non-zero and != f[pos]
            stream += f[:pos] + bytes((new,)) + f[pos + 1:]
            invalid(1)
            continue
        stream += f * (2 if op == "dup" else 1)
        in_error = False
        delivered.append(i)
        expect["duplicates"] += op == "dup"

    dec, out = decode_cut(bytes(stream), cuts)

    assert [s.volt_cv for s in out] == delivered
    assert [s.seq for s in out] == [(seq0 + i) & 0xFFFF for i in delivered]
    lost = (delivered[-1] - delivered[0] + 1 - len(delivered)) if delivered else 0
    c = dec.counters
    assert (c.received, c.lost, c.crc_errors, c.duplicates, c.resyncs) == (
        len(delivered), lost, expect["crc_errors"], expect["duplicates"], expect["resyncs"])
