"""docs/RESULTS.md's generated tables: run the benchmarks, keep their JSON, render the tables.

``python -m benchmarks.results`` re-renders docs/RESULTS.md from the saved JSON in
``docs/results/data/<run>.json``: in each generated section, the text between

    <!-- generated: NAME (python -m benchmarks.results) -->
    <!-- /generated: NAME -->

is replaced by what the section's render function makes of its runs' JSON; everything outside
the markers (the prose) is left as it is. ``--check`` writes nothing and exits 1 with one line
naming the first section whose text differs from what its saved JSON renders (0 when none does).
``--run NAME [NAME ...]`` (a run's or a section's name, or ``all``) first runs those benchmarks,
one at a time, as ``sys.executable -m benchmarks.MODULE ARGS`` from the checkout, takes the JSON
object each prints as its last line and saves it with its provenance (UTC date, git commit, load
average before and after, the command, the wall time), then re-renders.

The runs (data file name → benchmark command) are :data:`RUNS`; the sections (which runs each
reads, and how it renders them) are ``benchmarks.results_tables.SECTIONS``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "RESULTS.md"
DATA = ROOT / "docs" / "results" / "data"

RUNS: dict[str, tuple[str, ...]] = {
    "realdata": ("realdata",),
    "independent_plant": ("independent_plant",),
    "independent_plant_composed": ("independent_plant", "--cases", "--mixes", "--scaled"),
    "independent_plant_field": ("independent_plant", "--field"),
    "independent_plant_trains": ("independent_plant", "--trains"),
    "independent_plant_trains_field": ("independent_plant", "--trains", "--field"),
    "independent_plant_variants": ("independent_plant", "--cases", "--variants"),
    "independent_plant_variants_field": ("independent_plant", "--cases", "--variants", "--field"),
    "independent_plant_variants_trains": ("independent_plant", "--cases", "--variants", "--trains"),
    "independent_plant_variants_trains_field": ("independent_plant", "--cases", "--variants", "--trains", "--field"),
    "effects_table": ("effects_table",),
    "paper_table": ("paper_table", "docs/figures/paper_protocol.png"),
    "step_latency": ("step_latency",),
    "observer_loop_spin": ("observer_loop", "--spin", "--seconds", "24"),
    "observer_loop_load": ("observer_loop", "--load"),
    "machine_tail": ("machine_tail", "--seconds", "30"),
    "identify_speed": ("identify_speed",),
    "soak": ("soak", "--quiet"),
    "soak_can": ("soak", "--can", "--quiet"),
}
"""Each run: the module under ``benchmarks`` and its arguments, as docs/RESULTS.md names the command."""


class ResultsError(Exception):
    """A section cannot be rendered (no data file, no markers): the message names it."""


def command(run: str) -> str:
    module, *args = RUNS[run]
    return " ".join(["python", "-m", f"benchmarks.{module}", *args])


def begin_marker(section: str) -> str:
    return f"<!-- generated: {section} (python -m benchmarks.results) -->"


def end_marker(section: str) -> str:
    return f"<!-- /generated: {section} -->"


# ---------------------------------------------------------------- running


def _git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=False).stdout.strip()


def run_benchmark(run: str, data_dir: Path = DATA) -> dict:
    """Run one benchmark, save its last-line JSON with provenance to ``data_dir/<run>.json``."""
    module, *args = RUNS[run]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    load_before = os.getloadavg()
    started = datetime.datetime.now(datetime.timezone.utc)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", f"benchmarks.{module}", *args], cwd=ROOT, env=env,
                          stdout=subprocess.PIPE, text=True, check=False)
    seconds = time.perf_counter() - t0
    sys.stdout.write(proc.stdout)
    lines = [ln for ln in proc.stdout.splitlines() if ln.strip()]
    if proc.returncode != 0 or not lines:
        raise ResultsError(f"{command(run)} exited {proc.returncode}; nothing saved for {run!r}")
    try:
        result = json.loads(lines[-1])
    except json.JSONDecodeError as exc:
        raise ResultsError(f"{command(run)}: its last line is not JSON ({exc}); nothing saved for {run!r}") from None
    record = {
        "command": command(run),
        "date_utc": started.strftime("%Y-%m-%dT%H:%M:%SZ"),
        "commit": _git("rev-parse", "HEAD"),
        "code_changed_since_commit": bool(_git("status", "--porcelain", "--untracked-files=no", "--", ".",
                                               ":(exclude)docs")),
        "loadavg_before": [round(x, 2) for x in load_before],
        "loadavg_after": [round(x, 2) for x in os.getloadavg()],
        "seconds": round(seconds, 1),
        "result": result,
    }
    data_dir.mkdir(parents=True, exist_ok=True)
    (data_dir / f"{run}.json").write_text(json.dumps(record, indent=1, ensure_ascii=False) + "\n")
    print(f"results: {run}: saved ({record['seconds']:.0f} s, load {record['loadavg_before'][0]:.2f} → "
          f"{record['loadavg_after'][0]:.2f})", file=sys.stderr)
    return record


# ---------------------------------------------------------------- rendering


def load_result(section: str, run: str, data_dir: Path = DATA) -> dict:
    """The benchmark JSON saved for ``run``; a missing file names the section and how to make it."""
    path = data_dir / f"{run}.json"
    if not path.exists():
        raise ResultsError(f"section {section!r}: no data file {path.name} in {data_dir} "
                           f"(make it with: python -m benchmarks.results --run {run})")
    return json.loads(path.read_text())["result"]


def render_section(section, data_dir: Path = DATA) -> str:
    """One section's generated text from its runs' saved JSON."""
    return section.render(*(load_result(section.name, run, data_dir) for run in section.runs)).strip("\n")


def _span(text: str, section: str) -> tuple[int, int]:
    """Start and end of the text between the section's markers (each must appear once, in order)."""
    begin, end = begin_marker(section), end_marker(section)
    if text.count(begin) != 1 or text.count(end) != 1 or text.index(end) < text.index(begin):
        raise ResultsError(f"section {section!r}: docs/RESULTS.md needs exactly one '{begin}' followed by "
                           f"one '{end}'")
    return text.index(begin) + len(begin), text.index(end)


def replace_section(text: str, section: str, body: str) -> str:
    """``text`` with the content between the section's markers replaced by ``body`` (a blank line
    either side, so that a table after the marker is a table)."""
    i, j = _span(text, section)
    return text[:i] + "\n\n" + body.strip("\n") + "\n\n" + text[j:]


def _check_known(text: str, sections) -> None:
    known = {s.name for s in sections}
    for name in re.findall(r"<!-- generated: (\S+) \(python -m benchmarks\.results\) -->", text):
        if name not in known:
            raise ResultsError(f"section {name!r}: docs/RESULTS.md has its markers but no such section is defined")


def render_doc(text: str, sections, data_dir: Path = DATA) -> str:
    """``text`` with every section regenerated from the saved JSON."""
    _check_known(text, sections)
    for section in sections:
        text = replace_section(text, section.name, render_section(section, data_dir))
    return text


def first_difference(text: str, sections, data_dir: Path = DATA) -> str | None:
    """The name of the first section whose text differs from what its saved JSON renders, or None."""
    _check_known(text, sections)
    for section in sections:
        if replace_section(text, section.name, render_section(section, data_dir)) != text:
            return section.name
    return None


def runs_named(names: list[str], sections) -> list[str]:
    """Run names from ``names``: a run, a section (all of its runs) or ``all``."""
    by_section = {s.name: s.runs for s in sections}
    out: list[str] = []
    for name in names:
        if name == "all":
            picked = list(RUNS)
        elif name in by_section:
            picked = list(by_section[name])
        elif name in RUNS:
            picked = [name]
        else:
            raise ResultsError(f"no run or section {name!r} (runs: {', '.join(RUNS)})")
        out += [r for r in picked if r not in out]
    return out


def main(argv: list[str] | None = None) -> int:
    from benchmarks.results_tables import SECTIONS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--run", nargs="+", metavar="NAME", help="run these benchmarks first (a run, a section, all)")
    mode.add_argument("--check", action="store_true", help="exit 1 if docs/RESULTS.md differs from its data")
    args = ap.parse_args(argv)
    try:
        if args.check:
            name = first_difference(DOC.read_text(), SECTIONS)
            if name is not None:
                print(f"docs/RESULTS.md: section {name!r} differs from what docs/results/data renders "
                      "(python -m benchmarks.results re-renders it)")
                return 1
            return 0
        for run in runs_named(args.run or [], SECTIONS):
            run_benchmark(run)
        text = DOC.read_text()
        new = render_doc(text, SECTIONS)
        if new != text:
            DOC.write_text(new)
        print(f"docs/RESULTS.md: {len(SECTIONS)} sections rendered" + (", changed" if new != text else ", unchanged"))
        return 0
    except ResultsError as exc:
        print(f"benchmarks.results: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
