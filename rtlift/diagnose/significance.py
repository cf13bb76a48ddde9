"""Is a change significant on the held-out records? The test every member of a combination must
pass (:func:`significant_gain`: the relative RMSE gain, a Diebold–Mariano t over blocks, no
record worse, ρ not lower; :mod:`rtlift.diagnose.selection`'s module docstring, step 4), and the
rows of the report's table of the combinations compared (:func:`combination`), with the two
errors a row carries (:func:`pooled_rmse`, :func:`level_free_rmse`): what the selection engine
(:mod:`rtlift.diagnose.selection`) applies to every model kind.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rtlift.core.metrics import scores
from rtlift.diagnose.diagnosis import DiagnoseOptions


def pooled_rmse(errs: list[np.ndarray]) -> float:
    """The RMSE of the validation records' errors pooled."""
    return float(np.sqrt(np.mean(np.concatenate(errs) ** 2)))


def level_free_rmse(errs: list[np.ndarray]) -> float:
    """The pooled RMSE with each record's own mean error taken out: what the lift diagnosis's
    choice between admissible combinations compares (:mod:`rtlift.diagnose.lift`, step 4)."""
    return pooled_rmse([e - np.mean(e) for e in errs])


def significant_gain(before: list[np.ndarray], after: list[np.ndarray], measured: np.ndarray, block: int,
                     opt: DiagnoseOptions) -> tuple[bool, str]:
    """Errors ``after`` against ``before`` per record (``measured`` the records' outputs, pooled):
    relative RMSE gain ≥ ``opt.min_gain``, a Diebold–Mariano t ≥ ``opt.min_t`` over ``block``-sample
    blocks of the squared-error differences, no record worse by more than 1 %, and ρ not lower by
    more than 0.005 (a change that shrinks the signal can lower RMSE while the fit gets worse)."""
    rb, ra = pooled_rmse(before), pooled_rmse(after)
    gain = 1.0 - ra / rb if rb > 0 else 0.0
    diffs = []
    for b, a in zip(before, after, strict=True):
        d = b**2 - a**2
        nb = max(1, d.size // block)
        diffs += [float(np.mean(x)) for x in np.array_split(d, nb)]
    da = np.asarray(diffs)
    t = float(da.mean() / (da.std(ddof=1) / np.sqrt(da.size))) if da.size > 1 and da.std() > 0 else 0.0
    worst = max(float(np.sqrt(np.mean(a**2)) / np.sqrt(np.mean(b**2))) for b, a in zip(before, after, strict=True))
    dcorr = (scores(measured, measured - np.concatenate(after))["corr"]
             - scores(measured, measured - np.concatenate(before))["corr"])
    ok = gain >= opt.min_gain and t >= opt.min_t and worst <= 1.01 and dcorr >= -0.005
    why = (f"validation RMSE {rb:.5g} -> {ra:.5g} ({100 * gain:+.1f} %), t = {t:.1f} over "
           f"{da.size} blocks of {block} samples, worst record x{worst:.3f}, rho {dcorr:+.4f}")
    return ok, why


def combination(members: tuple[str, ...] | list[str], errors: list[np.ndarray], parameters: int | None,
                admissible: bool, why: str) -> dict[str, Any]:
    """One row of the report's ``selection.combinations``: the members, their pooled validation
    RMSE and its level-free twin (from their ``errors`` on the validation records), the parameters
    they spend (``None``: not counted — a failed fit, a generic structure), whether the row may be
    chosen and why."""
    return {"members": list(members), "validation_rmse": pooled_rmse(errors),
            "level_free_rmse": level_free_rmse(errors), "parameters": parameters,
            "admissible": admissible, "why": why}

