"""Soak: an hour of 400 Hz serial frames (1.44 M samples) through the decoder and the
observer loop as fast as possible, with faults sprinkled in — nothing lost, memory flat.
``--can``: the same hour as CAN frames (three per sample) through ``CanAssembler``.

The frames are the simulated bench's (``hil_sim.experiments.daq_stream``), encoded with
``firmware_io.serial_codec.encode_sample``; a seeded :class:`testkit.wire_faults.FaultInjector` changes the wire
and records exactly what it injected, hence the counters the decoder must end with. The
bytes reach the decoder in reads of random size (1–4096 bytes, as ``in_waiting`` gives
them); every sample goes through ``firmware_io.Converter`` and ``rtlift.app.live.ObserverLoop``
(predict-only steps for gaps and flagged samples) exactly as in ``rtlift observe``.

Checks: decoder counters == injected (received, lost, crc_errors, duplicates, resyncs,
events); loop steps == received, fills == lost; observer updates + rejected + missing ==
samples sent, missing == flagged + lost. Memory: VmRSS from /proc/self/status after a
warm-up (the first minute of data) and at the end.

With ``--can`` the wire is three 8-byte frames per sample (u8 ``seq``, the DBC's layout) fed
to :class:`~firmware_io.can_codec.CanAssembler` as ``rtlift observe --can`` does after
python-can's driver, with the CAN fault mix (:data:`CAN_RATES`): truncated frames (DLC 4),
dropped, duplicated, late samples, reordered frames, error frames, other nodes' frames,
flagged and absurd samples. The frames are encoded by cantools from the DBC.

Prints JSON as its last line: ``samples``, ``faults_injected``, ``accounted_exactly``,
``rss_growth_mb``, ``seconds`` (and the details).
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from benchmarks._common import emit  # noqa: E402
from testkit.wire_faults import can_soak, soak  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=60.0, help="minutes of 400 Hz data (default 60: 1.44 M samples)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--can", action="store_true", help="CAN frames (three per sample) instead of serial packets")
    ap.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    args = ap.parse_args()
    if not args.minutes > 0:
        ap.error("--minutes must be positive")
    result = (can_soak if args.can else soak)(args.minutes, args.seed, progress=not args.quiet)
    result["link"] = "can" if args.can else "serial"
    print(f"soak ({result['link']}): {result['samples']} samples, {result['faults_injected']} faults, "
          f"accounted exactly: {result['accounted_exactly']}, RSS growth {result['rss_growth_mb']} MiB, "
          f"{result['seconds']} s")
    emit(result)


if __name__ == "__main__":
    main()
