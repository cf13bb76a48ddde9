"""CAN wire format (PROTOCOL.md "CAN bus"): the package DBC and the assembly of samples by
``seq`` with exact counters, including property tests over frame orders and faults."""

from __future__ import annotations

import struct
from types import SimpleNamespace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_io.can_codec import (
    ACT_ID,
    FT_FORCE_ID,
    FT_TORQUE_ID,
    CanAssembler,
    encode_sample_frames,
    load_dbc,
)

PROTOCOL_TABLE = {
    # id: (name, [(signal, start bit, length, signed, scale)])
    0x100: ("CMD", [("cmd_seq", 0, 8, False, 1), ("envelope_cv", 8, 16, False, 0.01),
                    ("burst_period_ms", 24, 16, False, 1), ("flags", 40, 8, False, 1),
                    ("watchdog_ms_div10", 48, 8, False, 10), ("spare", 56, 8, False, 1)]),
    0x101: ("ACT", [("seq", 0, 8, False, 1), ("volt_cv", 8, 16, False, 0.01),
                    ("envelope_cv", 24, 16, False, 0.01), ("status", 40, 8, False, 1),
                    ("t_10us", 48, 16, False, 1e-5)]),
    0x102: ("FT_FORCE", [("seq", 0, 8, False, 1), ("fx", 8, 16, True, 0.001), ("fy", 24, 16, True, 0.001),
                         ("fz", 40, 16, True, 0.001), ("cmd_seq", 56, 8, False, 1)]),
    0x103: ("FT_TORQUE", [("seq", 0, 8, False, 1), ("tx", 8, 16, True, 1e-5), ("ty", 24, 16, True, 1e-5),
                          ("tz", 40, 16, True, 1e-5), ("spare", 56, 8, False, 1)]),
}


@pytest.mark.parametrize("frame_id", sorted(PROTOCOL_TABLE))
def test_dbc_frames_are_exactly_the_protocol_table(frame_id):
    name, signals = PROTOCOL_TABLE[frame_id]
    msg = load_dbc().get_message_by_frame_id(frame_id)
    assert msg.name == name and msg.length == 8 and not msg.is_extended_frame
    got = [(s.name, s.start, s.length, s.is_signed, s.scale) for s in msg.signals]
    assert [g[:4] for g in got] == [s[:4] for s in signals]
    assert [g[4] for g in got] == pytest.approx([s[4] for s in signals], rel=1e-12)
    assert all(s.byte_order == "little_endian" for s in msg.signals)


def test_encoded_frames_are_little_endian_at_the_protocol_offsets():
    frames = dict(encode_sample_frames(200, 0xBEEF, 6000, 5999, 0x0B, (-1, 2, -32768), (32767, 0, -5)))
    assert struct.unpack("<BHHBH", frames[ACT_ID]) == (200, 6000, 5999, 0x0B, 0xBEEF)
    assert struct.unpack("<BhhhB", frames[FT_FORCE_ID]) == (200, -1, 2, -32768, 0)
    assert struct.unpack("<BhhhB", frames[FT_TORQUE_ID]) == (200, 32767, 0, -5, 0)


def frames_of(seq: int, tag: int = 0) -> list[tuple[int, bytes]]:
    return encode_sample_frames(seq, seq * 250, tag, 100, 0x01, (1000, -2000, 3000), (100, -200, 300))


def test_a_sample_is_complete_when_its_three_frames_arrived_in_any_order():
    asm = CanAssembler()
    act, force, torque = frames_of(9, tag=77)
    assert asm.feed(*torque) is None and asm.feed(*act) is None
    s = asm.feed(*force)
    assert (s.seq, s.t_us, s.volt_cv, s.envelope_cv, s.status) == (9, 22500, 77, 100, 1)
    assert s.ft == pytest.approx((1.0, -2.0, 3.0, 0.001, -0.002, 0.003), rel=1e-12)


def test_an_incomplete_sample_is_lost_when_a_newer_seq_completes_across_the_u8_wrap():
    asm = CanAssembler()
    for fid, data in frames_of(254):
        asm.feed(fid, data)
    asm.feed(*frames_of(255)[0])  # 255 incomplete
    out = [asm.feed(fid, data) for fid, data in frames_of(1)]  # 0 never sent
    assert out[-1].seq == 1 and asm.counters.lost == 2 and asm.counters.received == 2


def test_wrong_dlc_and_error_frames_are_invalid_and_foreign_ids_are_ignored():
    asm = CanAssembler()
    act, force, torque = frames_of(3)
    asm.feed(act[0], act[1][:4])
    asm.feed_message(SimpleNamespace(is_error_frame=True, is_remote_frame=False, is_extended_id=False,
                                     arbitration_id=0, data=b""))
    asm.feed(0x7FF, b"\x03" * 8)
    asm.feed_message(SimpleNamespace(is_error_frame=False, is_remote_frame=False, is_extended_id=True,
                                     arbitration_id=ACT_ID, data=act[1]))
    assert asm.counters.crc_errors == 2 and asm.counters.received == 0


def test_a_repeated_frame_is_a_duplicate_before_and_after_completion():
    asm = CanAssembler()
    act, force, torque = frames_of(5)
    asm.feed(*act)
    asm.feed(*act)
    asm.feed(*force)
    asm.feed(*torque)
    asm.feed(*torque)
    assert (asm.counters.received, asm.counters.duplicates, asm.counters.lost) == (1, 2, 0)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=16), st.integers(0, 0x7FF), st.booleans())
def test_assembler_never_raises_on_arbitrary_frames(data, frame_id, ours):
    asm = CanAssembler()
    for _ in range(3):
        asm.feed(ACT_ID + (frame_id % 3) if ours else frame_id, data)
    assert asm.counters.received <= 1


OP = st.sampled_from(["ok", "ok", "ok", "ok", "drop", "dup", "short"])


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 255),
       st.lists(st.tuples(st.permutations([0, 1, 2]), st.tuples(OP, OP, OP)), min_size=1, max_size=120))
def test_counters_are_exact_for_any_frame_order_drops_duplicates_and_bad_frames(seq0, plan):
    asm = CanAssembler()
    out = []
    delivered, expect_dup, expect_bad = [], 0, 0
    for i, (order, ops) in enumerate(plan):
        frames = frames_of((seq0 + i) & 0xFF, tag=i)
        for k in order:
            fid, data = frames[k]
            op = ops[k]
            if op == "drop":
                continue
            if op == "short":
                expect_bad += 1
                data = data[:5]
            for _ in range(2 if op == "dup" else 1):
                s = asm.feed(fid, data)
                if s is not None:
                    out.append(s)
            expect_dup += op == "dup"
        if all(op in ("ok", "dup") for op in ops):
            delivered.append(i)
    assert [s.volt_cv for s in out] == delivered
    lost = (delivered[-1] - delivered[0] + 1 - len(delivered)) if delivered else 0
    c = asm.counters
    assert (c.received, c.lost, c.duplicates, c.crc_errors) == (len(delivered), lost, expect_dup, expect_bad)


def test_the_first_sample_is_judged_like_any_other():
    """Joined mid-sample: the complete first sample is delivered; the incomplete one before
    it is one resync, not a loss."""
    frames = [encode_sample_frames(s, s * 250, 100, 50, 0, (1, 2, 3), (4, 5, 6)) for s in range(4)]
    asm = CanAssembler()
    got = [asm.feed(*f) for f in frames[0][1:] + frames[1] + frames[2]]
    assert [s.seq for s in got if s is not None] == [1, 2]
    assert (asm.counters.received, asm.counters.resyncs, asm.counters.lost) == (2, 1, 0)
    asm = CanAssembler()
    got = [asm.feed(*f) for f in frames[0][::-1] + frames[1]]  # complete, any order
    assert [s.seq for s in got if s is not None] == [0, 1] and asm.counters.resyncs == 0
