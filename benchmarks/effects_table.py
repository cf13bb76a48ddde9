"""Effects table: inject each bench effect after identification, diagnose, error before/after.

The hybrid model is identified on a clean standard campaign (seed 1). For every effect of
``hil_sim.effects`` (parameters drawn from its documented range with ``--seed``, default 100;
``--defaults`` uses the documented defaults) the training record (sine k = 0.125, seed 11) and
two validation records (sine k = 0.125 seed 12, random seed 13) are measured with the effect
and diagnosed. Reported per effect: pooled validation RMSE of the plain model on the clean
records (same seeds and noise) and on the records with the effect (``rmse_before``), of the
augmented model (``rmse_after``), ``found`` (the effect accepted), ``named`` (accepted, or named
by the residual tests without being accepted), and true vs estimated parameters.

Prints a markdown table and, as its last line, one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from hil_sim.effects import EFFECTS
from hil_sim.experiments import run_experiment
from rtlift.diagnose import diagnose
from rtlift.effects.surgery import predict
from rtlift.identify import identify_hybrid


def bench_model():
    """The hybrid model identified on the bench's clean standard campaign (seed 1)."""
    camp = {n: run_experiment(n, seed=1).to_record() for n in ("static", "single_burst", "sine_k0125")}
    return identify_hybrid(camp["static"], camp["single_burst"], camp["sine_k0125"]).model


def records(effects: list, seeds: tuple[int, int, int] = (11, 12, 13)) -> tuple:
    """The training record (sine k = 0.125) and the two validation records (sine k = 0.125,
    random), measured with ``effects``, at noise ``seeds``."""
    def rec(exp: str, seed: int, name: str):
        r = run_experiment(exp, seed=seed, effects=effects).to_record()
        r.name = name
        return r
    return rec("sine_k0125", seeds[0], "train"), [rec("sine_k0125", seeds[1], "val"),
                                                   rec("random", seeds[2], "valr")]


def pooled(model, recs) -> float:
    """Pooled RMSE over whole records, scored as rtlift validate scores them."""
    errs = [r.dcl - predict(model, r).total for r in recs]
    return float(np.sqrt(np.mean(np.concatenate(errs) ** 2)))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=100)
    ap.add_argument("--defaults", action="store_true")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    model = bench_model()
    clean_train, clean_val = records([])
    clean = pooled(model, clean_val)
    diag0 = diagnose(model, clean_train, clean_val)
    out: dict = {"clean_rmse": clean, "clean_accepted": [f"{e['name']} ({e['kind']})" for e in
                                                          diag0.report["effects"] if e["accepted"]],
                 "effects": {}}
    for name, info in EFFECTS.items():
        eff = info.draw(np.random.default_rng(args.seed)) if not args.defaults else \
            type(info.draw(np.random.default_rng(0)))(name, dict(info.defaults))
        train, val = records([eff])
        diag = diagnose(model, train, val)
        before = pooled(model, val)
        after = pooled(diag.augmented, val)
        entry = next(e for e in diag.report["effects"] if e["name"] == name)
        named = entry["accepted"] or any(name in u for u in diag.report["unexplained"])
        out["effects"][name] = {
            "rmse_before": before, "rmse_after": after,
            "found": bool(entry["accepted"] and entry["kind"] == "effect"),
            "named": bool(named), "params_true": dict(eff.params), "params_estimated": entry["params"],
            "accepted": [f"{e['name']} ({e['kind']})" for e in diag.report["effects"] if e["accepted"]],
            "recovered_fraction": (before - after) / (before - clean) if before > clean else None,
        }
    out["seconds"] = round(time.perf_counter() - t0, 1)
    print(f"clean validation RMSE {clean:.5f} (sine k=0.125 seed 12 + random seed 13); the clean records "
          f"accept: {', '.join(out['clean_accepted']) or 'nothing'}")
    print("| effect | true parameters | estimated | RMSE before | RMSE after | recovered | found | accepted |")
    print("|---|---|---|---|---|---|---|---|")
    for name, e in out["effects"].items():
        tp = ", ".join(f"{k}={v:.4g}" for k, v in e["params_true"].items())
        ep = ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                       for k, v in e["params_estimated"].items() if k not in ("phase_rad", "offset"))
        rec = "–" if e["recovered_fraction"] is None else f"{100 * e['recovered_fraction']:.0f} %"
        found = "yes" if e["found"] else ("named, not accepted" if e["named"] else "no")
        print(f"| {name} | {tp} | {ep} | {e['rmse_before']:.5f} | {e['rmse_after']:.5f} | {rec} | {found} | "
              f"{', '.join(e['accepted']) or '—'} |")
    print(json.dumps(out, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
