"""Links behind one interface: configuration, one-line errors, timeouts, disconnects.
(In-process transports only: pyserial's ``loop://`` and python-can's ``virtual`` bus.)"""

from __future__ import annotations

import time

import can
import pytest

from firmware_io import LinkError, open_link
from firmware_io.can_codec import encode_sample_frames
from firmware_io.links import link_config, parse_can_spec
from firmware_io.serial_codec import encode_sample
from rtlift.core.errors import UserError

NO_GAPS = {k: 0 for k in ("reconnects", "gap_lost", "gaps_unknown", "gap_lost_estimated")}
"""The reconnect counters of a link that never lost its device."""
NO_COMMANDS = {"commands_sent": 0, "commands_applied": 0, "watchdog_trips": 0}
"""The command counters of a link that sent no command to a device that applied none."""


def test_a_missing_serial_port_is_a_one_line_user_error(tmp_path):
    with pytest.raises(LinkError) as info:
        open_link({"kind": "serial", "port": str(tmp_path / "ttyNOPE")})
    assert isinstance(info.value, UserError)
    assert "\n" not in str(info.value) and "no such device" in str(info.value)


def test_an_unknown_can_interface_is_a_one_line_user_error():
    with pytest.raises(LinkError) as info:
        open_link({"kind": "can", "interface": "warpdrive", "channel": "0"})
    assert "\n" not in str(info.value) and "unknown CAN interface 'warpdrive'" in str(info.value)


def test_an_slcan_adapter_that_is_not_there_is_a_one_line_user_error(tmp_path):
    with pytest.raises(LinkError) as info:
        open_link({"kind": "can", "interface": "slcan", "channel": str(tmp_path / "ttyACM9")})
    assert "\n" not in str(info.value) and "cannot open" in str(info.value)


@pytest.mark.parametrize("config", [{"kind": "usb"}, {"kind": "serial"}, {"kind": "can", "channel": "x"},
                                    {"kind": "serial", "port": "loop://", "baud": 1},
                                    {"kind": "serial", "port": "loop://", "spin": 2.5},
                                    {"kind": "serial", "port": "loop://", "spin": "fast"}])
def test_incomplete_or_unknown_configs_are_user_errors(config):
    with pytest.raises(LinkError):
        open_link(config)


def test_a_spin_window_in_ms_is_kept_in_seconds():
    with open_link({"kind": "serial", "port": "loop://", "spin": 0.5}) as link:
        assert link.spin is True and link.spin_window_s == pytest.approx(5e-4)
    with open_link({"kind": "serial", "port": "loop://", "spin": True}) as link:
        assert link.spin is True and link.spin_window_s is None


def test_cli_forms_parse_into_link_configs():
    assert link_config(serial_port="/dev/ttyACM0") == {"kind": "serial", "port": "/dev/ttyACM0"}
    assert parse_can_spec("slcan:/dev/pts/3") == {"kind": "can", "interface": "slcan",
                                                   "channel": "/dev/pts/3", "bitrate": 500000}
    assert link_config(can_spec="virtual:bench", log="x.asc")["log"] == "x.asc"
    for bad in ("slcan", ":x", "pcan:"):
        with pytest.raises(LinkError):
            parse_can_spec(bad)
    with pytest.raises(LinkError):
        link_config(serial_port="a", can_spec="virtual:0")


def test_serial_link_decodes_what_it_reads_and_times_out_on_silence():
    with open_link({"kind": "serial", "port": "loop://"}) as link:
        link._ser.write(b"\x00" + encode_sample(41, 0, 100, (2_000_000,) * 6, 1, 200))
        s = link.recv(1.0)
        assert (s.seq, s.volt_cv, s.envelope_cv, s.ft[0]) == (41, 100, 200, 2.0)
        t0 = time.perf_counter()
        assert link.recv(0.1) is None
        assert time.perf_counter() - t0 >= 0.09   # waited for the timeout (how long after: benchmarks/pacing.py)
        assert not link.disconnected


def test_can_link_assembles_samples_from_any_python_can_interface():
    config = {"kind": "can", "interface": "virtual", "channel": "test_io_links_assemble",
              "receive_own_messages": False}
    with open_link(config) as link, can.Bus(interface="virtual", channel=config["channel"],
                                            ignore_config=True) as device:
        for seq in range(3):
            for fid, data in encode_sample_frames(seq, seq, 10 * seq, 0, 1, (1, 2, 3), (4, 5, 6)):
                device.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False))
        device.send(can.Message(is_error_frame=True))
        got = [link.recv(1.0) for _ in range(3)]
        assert [s.volt_cv for s in got] == [0, 10, 20]
        assert link.recv(0.05) is None
        assert link.counters.as_dict() == {"received": 3, "crc_errors": 1, "lost": 0, "duplicates": 0,
                                           "events": 0, "resyncs": 0, **NO_GAPS, **NO_COMMANDS}


def test_samples_yields_none_on_silence_and_ends_when_the_link_is_closed():
    link = open_link({"kind": "serial", "port": "loop://"})
    it = link.samples(0.05)
    assert next(it) is None
    link.close()
    assert list(it) == []


@pytest.mark.parametrize("value", ["yes", {"retry": 1}, {"give_up_s": -1}, {"first_delay_s": 0}, -3])
def test_bad_reconnect_options_are_one_line_user_errors(value):
    with pytest.raises(LinkError) as info:
        open_link({"kind": "serial", "port": "loop://", "reconnect": value})
    assert "\n" not in str(info.value) and str(info.value).startswith("reconnect:")


def test_reconnect_options_parse():
    from firmware_io.links import Reconnect

    assert Reconnect.from_config(None) is None and Reconnect.from_config(False) is None
    assert Reconnect.from_config(True) == Reconnect() and Reconnect.from_config(30).give_up_s == 30
    assert Reconnect.from_config({"also": ["/dev/ttyACM1"]}).also == ("/dev/ttyACM1",)
