"""Calibration in one place: the serial decoder turns counts into N and N·m through the
bench's :class:`~firmware_io.calibration.Calibration` (its ``si_from_counts``) and holds no scale
of its own; a raw serial log read back with a calibration is scaled by it."""

from __future__ import annotations

import inspect

import numpy as np

from firmware_io import read_log
from firmware_io.calibration import Calibration
from firmware_io.serial_codec import SerialDecoder, encode_sample

COUNTS = [(1000, -20, 300000, 5, -6, 7), (-2**31, 2**31 - 1, 0, 123456, -654321, 1)]
RIG = Calibration(counts_per_n=2.0e5, counts_per_nm=3.0e8)
"""A transducer with another scale than PROTOCOL.md's default (1e6 counts/N, 1e9 counts/N·m)."""


def _wire() -> bytes:
    return b"".join(encode_sample(i + 1, 2500 * i, 100, c, 1, 50, cmd_seq=0) for i, c in enumerate(COUNTS))


def test_the_decoder_scales_counts_by_the_calibration_exactly_as_its_array_form():
    for cal in (Calibration(), RIG):
        out = []
        dec = SerialDecoder(out.append, cal)
        dec.feed(b"\x00" + _wire())
        assert [s.ft for s in out] == [cal.si_from_counts(*c) for c in COUNTS]
        np.testing.assert_array_equal(np.array([s.ft for s in out]), cal.ft_from_counts(np.array(COUNTS)))
    assert out[0].ft[2] == 300000 / 2.0e5 == 1.5 and out[0].ft[5] == 7 / 3.0e8


def test_the_decoder_holds_no_scale_of_its_own():
    params = inspect.signature(SerialDecoder).parameters
    assert not any("counts" in p for p in params), list(params)
    src = inspect.getsource(SerialDecoder)
    assert "counts_per" not in src and "1.0e6" not in src and "1e6" not in src


def test_a_serial_log_is_scaled_by_the_calibration_it_is_read_with(tmp_path):
    log = tmp_path / "run.bin"
    log.write_bytes(b"\x00" + _wire())
    default = [s.ft for s in read_log(log)]
    rig = [s.ft for s in read_log(log, RIG)]
    assert len(rig) == len(COUNTS) and rig == [RIG.si_from_counts(*c) for c in COUNTS]
    np.testing.assert_allclose(np.array(rig)[:, :3], 5.0 * np.array(default)[:, :3], rtol=1e-15)
    np.testing.assert_allclose(np.array(rig)[:, 3:], np.array(default)[:, 3:] * 1e9 / 3.0e8, rtol=1e-15)
