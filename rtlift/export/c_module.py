"""``rtlift export c``: the model and its observer as one C99 module a firmware calls at 400 Hz.

The module is the translation of the compiled Python step (:mod:`rtlift.observer.compiled`,
:mod:`rtlift.blocks.compiled`, :mod:`rtlift.blocks.compiled_interaction`,
:mod:`rtlift.blocks.compiled_stages`): the same recurrences in the same order, on the numbers
the Python observer binds (its packed parameters and its state after ``reset``, read by
:func:`~rtlift.export.filter_spec.kernel_arrays`), written as ``static const`` data, the sizes as
macros (the loops' trip counts known to the compiler). The step's text is the template
``templates/observer.c.in``; this module writes the header, the data, ``NAME_init`` and the
test program with its vector file (:mod:`rtlift.export.vectors`).

Every effect the compiled step takes is exported (``delay``, ``actuator_fade``, the
``hysteresis`` factor, the textbook ``f(y)`` nonlinearity, ``zero_drift``,
``sensor_resonance``, ``periodic_disturbance``, the ``interaction`` structure with its
``delivered_envelope``); a model the compiled step does not take is refused with one line
naming the part (:func:`~rtlift.export.filter_spec.bound_observer`).

Not carried over: the mean log-likelihood monitor (``Observer.nll``, it needs ``log``); the
module counts updates, rejections, missing samples, bad inputs, Σ NIS and NIS in the 95 % band.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from rtlift.blocks.compiled_stages import HYSTERESIS
from rtlift.export.filter_spec import ExportError, FilterSpec, bound_observer, filter_spec, kernel_arrays
from rtlift.export.vectors import reference_vectors, test_program, write_vectors
from rtlift.model.hybrid import HybridModel
from rtlift.observer import ObserverConfig
from rtlift.observer import config as oc

PRECISIONS = ("double", "single")
GAINS = ("steady", "full")
@dataclass(frozen=True)
class CExport:
    """What :func:`export_c` wrote and what the step costs: the paths and the multiply–adds per
    step (counted from the loops' trip counts: model, filter)."""

    header: Path
    source: Path
    test: Path
    vectors: Path
    prefix: str
    precision: str
    gain: str
    macs_model: int
    macs_filter: int

    @property
    def macs(self) -> int:
        return self.macs_model + self.macs_filter


@dataclass(frozen=True)
class ModelParts:
    """The model's compiled-step numbers, unpacked from its packed array (layouts in
    :func:`rtlift.blocks.compiled.pack_parameters`, :func:`rtlift.blocks.compiled_interaction.pack_interaction`,
    :func:`rtlift.blocks.compiled_stages.with_outputs`)."""

    ints: dict[str, int]
    scalars: dict[str, float]
    arrays: dict[str, np.ndarray]
    out_stages: list[tuple[int, bool, float, np.ndarray]]


def unpack_model(interaction: bool, a: dict[str, np.ndarray]) -> ModelParts:
    """:class:`ModelParts` from :func:`~rtlift.export.filter_spec.kernel_arrays`' arrays."""
    par = a["mpar"]
    n_taps, n_sec, n = a["buf"].size // 2, a["z"].size // 2, a["x"].size
    form, n_table = int(par[0]), int(par[1])
    o = 2 + n_taps
    sos = par[o:o + 5 * n_sec]
    o += 5 * n_sec
    arrays = {"TAPS": par[2:2 + n_taps], "SOS": sos if n_sec else np.array([1.0, 0, 0, 0, 0]),
              "WA": par[o:o + n * n], "WB": par[o + n * n:o + n * n + n], "WC": par[o + n * n + n:o + n * n + 2 * n]}
    o += n * n + 2 * n
    arrays.update(XS=par[o:o + n_table], FS=par[o + n_table:o + 2 * n_table],
                  SLOPES=par[o + 2 * n_table:o + 3 * n_table - 1])
    o += 3 * n_table - 1 + n
    fade = a["fade"]
    end = par.size
    hyst = par[end - HYSTERESIS:end - HYSTERESIS + 6]
    ints = {"N_TAPS": n_taps, "N_SEC": max(n_sec, 1), "N_X": n, "N_TABLE": n_table, "FORM": form,
            "N_DELAY": a["d_cmu"].size, "FADE": int(fade[0] != 0.0), "HYST": int(hyst[0] != 0.0),
            "INTERACTION": int(interaction), "LIFT_N": 0, "N_OUT": int(par[end - 2]), "OUT_NMAX": int(par[end - 3])}
    scalars: dict[str, float] = {}
    if ints["FADE"]:
        scalars.update(FADE_F=fade[1], FADE_TAU=fade[2], FADE_DT=fade[3])
        ints["FADE_TIME"] = int(fade[4] != 0.0)
    if ints["HYST"]:
        scalars.update(HYST_M=hyst[1], HYST_G=hyst[2], HYST_W=hyst[3], HYST_LAM=hyst[4])
        ints["HYST_LIFT"] = int(hyst[5] != 0.0)
    if interaction:
        scalars.update(IN_LAM=par[o], IN_B=par[o + 1], IN_SCALE=par[o + 2], MC_LAM=par[o + 3], MC_B=par[o + 4],
                       MC_INV_D=par[o + 5])
        k = int(par[o + 6])
        g = o + 7
        ints["N_KNOTS"] = k
        arrays.update(KNOTS=par[g:g + k], GH=par[g + k:g + 2 * k], GH_SL=par[g + 2 * k:g + 3 * k - 1],
                      GM=par[g + 3 * k - 1:g + 4 * k - 1], GM_SL=par[g + 4 * k - 1:g + 5 * k - 2],
                      GS=par[g + 5 * k - 2:g + 6 * k - 2], GS_SL=par[g + 6 * k - 2:g + 7 * k - 3])
        lo = g + 7 * k - 3
        nl = int(par[lo + 2])
        ints["LIFT_N"] = nl
        if nl:
            scalars.update(LIFT_POWER=par[lo], LIFT_INV_CHORD=par[lo + 1])
            lo += 3
            arrays.update(LGRID=par[lo:lo + nl], LGAIN=par[lo + nl:lo + 2 * nl],
                          LSLOPES=par[lo + 2 * nl:lo + 3 * nl - 1])
    stages = []
    o = end - int(par[end - 1])
    for _ in range(ints["N_OUT"]):
        m = int(par[o])
        stages.append((m, par[o + 1] != 0.0, float(par[o + 2]), par[o + 3:o + 3 + m * m + 2 * m].copy()))
        o += 3 + m * m + 2 * m
    return ModelParts(ints, {k: float(v) for k, v in scalars.items()}, arrays, stages)


class _Writer:
    """C text for one precision: numbers, arrays and scalars as ``static const``."""

    def __init__(self, single: bool) -> None:
        self.single = single

    def number(self, v: float) -> str:
        v = float(v)
        if np.isinf(v):
            return ("" if v > 0 else "-") + ("HUGE_VALF" if self.single else "HUGE_VAL")
        if not np.isfinite(v):
            raise ExportError("cannot export to C: the model holds a NaN parameter")
        if not self.single:
            return repr(v)
        s = f"{float(np.float32(v)):.9g}"
        return (s if any(ch in s for ch in ".e") else s + ".0") + "f"

    def array(self, name: str, values: np.ndarray, kind: str = "real") -> str:
        vals = [str(int(v)) for v in values] if kind == "int" else [self.number(v) for v in np.ravel(values)]
        rows = [", ".join(vals[i:i + 6]) for i in range(0, len(vals), 6)]
        body = ",\n    ".join(rows)
        return f"static const {kind} {name}[{max(len(vals), 1)}] = {{\n    {body or '0'}\n}};\n"

    def scalar(self, name: str, v: float) -> str:
        return f"static const real {name} = {self.number(v)};\n"


def _c_identifier(prefix: str) -> str:
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]{0,30}", prefix):
        raise ExportError(f"--prefix {prefix!r}: must be a C identifier of at most 31 characters")
    return prefix


def _header(pfx: str, parts: ModelParts, spec: FilterSpec, real: str, source: str) -> str:
    i = parts.ints
    guard = pfx.upper() + "_H"
    fields = [f"PFX_real buf[{2 * i['N_TAPS']}];   /* the last Cμ′, twice (a mirrored ring) */",
              "int pos;",
              f"PFX_real z[{2 * i['N_SEC']}];   /* the high-pass sections' state */",
              f"PFX_real x[{i['N_X']}];   /* the Wiener LTI's state */",
              f"PFX_real sstate[{4 + sum(m for m, *_ in parts.out_stages)}];"
              "   /* the fade's clock, the hysteresis memory, the output stages */"]
    if i["N_DELAY"]:
        fields += [f"PFX_real d_cmu[{i['N_DELAY']}];", f"PFX_real d_env[{i['N_DELAY']}];", "int d_pos;"]
    if i["INTERACTION"]:
        fields += ["PFX_real m_in;   /* the delivered envelope's burst memory q */",
                   "PFX_real m_conv;   /* the burst part's momentum m */"]
    d = spec.dim_x
    fields += [f"PFX_real xi[{d}];   /* the observer's state ξ */",
               f"PFX_real H[{d}];   /* the measurement row H(k) */"]
    if spec.full:
        fields += [f"PFX_real P[{d * d}];   /* the covariance, row-major */", f"PFX_real T[{d * d}];   /* scratch */",
                   f"PFX_real work[{d}];   /* scratch: P⁻Hᵀ */"]
    if spec.harmonics:
        fields += ["PFX_real prev_cmu;   /* the burst phase: Cμ(k−1), φ(k), P(k) */",
                   "int since, period, ripple_on;"]
    fields += ["PFX_real last_cmu, last_env;   /* the last finite inputs (held for a bad one) */",
               "PFX_real rejected_run;", "int gate_open;",
               "unsigned long sample, updates, rejected, missing, bad_inputs, nis_in_band;",
               "PFX_real nis_sum;   /* Σ NIS of the accepted updates */"]
    body = "\n".join("    " + f for f in fields)
    return f"""/* {pfx}.h — generated by rtlift export c ({source}); do not edit.
 * The hybrid lift model and its Kalman observer, {real} precision, --gain {"full" if spec.full else "steady"}.
 * Call {pfx}_init once, then {pfx}_step once per sample (400 Hz), Cμ and Cμ_env as the model
 * was identified on, the measured ΔCL or NAN when there is none. No malloc, no recursion. */
#ifndef {guard}
#define {guard}

typedef {real} PFX_real;

#define PFX_FLAG_MISSING {oc.FLAG_MISSING}
#define PFX_FLAG_REJECTED {oc.FLAG_REJECTED}
#define PFX_FLAG_GATE_RELEASED {oc.FLAG_GATE_RELEASED}
#define PFX_FLAG_BAD_INPUT {oc.FLAG_BAD_INPUT}

typedef struct {{
{body}
}} PFX_state;

typedef struct {{
    PFX_real dcl;          /* ΔĈL, the estimate */
    PFX_real model_dcl;    /* ΔCL of the model alone (open loop) */
    PFX_real innovation;   /* ν (NAN without a measurement) */
    PFX_real nis;          /* ν²/S (NAN without a measurement) */
    PFX_real bias;         /* b̂ */
    int flags;             /* PFX_FLAG_* bits */
}} PFX_out;

/* the model at rest, ξ = 0, P = P0, the burst phase unknown, the counters zero */
void PFX_init(PFX_state *st);
/* one sample: Cμ, Cμ_env, the measured ΔCL (NAN: predict only) */
void PFX_step(PFX_state *st, double cmu, double envelope, double dcl_measured, PFX_out *out);
/* the model alone (feedforward, an open-loop plant): ΔCL; a state of its own, not one PFX_step advances */
PFX_real PFX_model_step(PFX_state *st, double cmu, double envelope);

#endif
""".replace("PFX", pfx)


def _data(w: _Writer, parts: ModelParts, spec: FilterSpec, a: dict[str, np.ndarray]) -> str:
    """The macros and ``static const`` data the step's template reads (only what it reads:
    an unused static is an error under ``-Werror``)."""
    i = dict(parts.ints)
    i.update(DIM_X=spec.dim_x, N_WIENER=spec.n_wiener, BIAS=spec.bias, GAIN_H=spec.gain_h,
             RIPPLE_START=spec.ripple_start, HARMONICS=spec.harmonics, POWERS=spec.powers,
             MAX_PERIOD=spec.max_period, FULL_GAIN=int(spec.full), FLAG_MISSING=oc.FLAG_MISSING,
             FLAG_REJECTED=oc.FLAG_REJECTED, FLAG_GATE_RELEASED=oc.FLAG_GATE_RELEASED,
             FLAG_BAD_INPUT=oc.FLAG_BAD_INPUT)
    out = [f"#define {k} {v}\n" for k, v in i.items()]
    out += [w.scalar(k, v) for k, v in parts.scalars.items()]
    out += [w.array(k, v) for k, v in parts.arrays.items()]
    if parts.out_stages:
        at, flat = [], []
        for *_, abc in parts.out_stages:
            at.append(len(flat))
            flat.extend(abc.tolist())
        out += [w.array("OUT_N", np.array([m for m, *_ in parts.out_stages]), "int"),
                w.array("OUT_KNOWN", np.array([int(k) for _, k, *_ in parts.out_stages]), "int"),
                w.array("OUT_AT", np.array(at), "int"),
                w.array("OUT_D", np.array([dd for _, _, dd, _ in parts.out_stages])),
                w.array("OUT_PAR", np.array(flat))]
    rows, cols = np.nonzero(spec.F)
    out += [w.array("F_PTR", np.searchsorted(rows, np.arange(spec.dim_x + 1)), "int"),
            w.array("F_COL", cols, "int"), w.array("F_VAL", spec.F[rows, cols]),
            w.array("FG", spec.G), w.array("H_LIFT", spec.h_lift), w.array("H_FIXED", spec.h_fixed),
            w.scalar("GATE", spec.gate), w.scalar("MAX_REJ", float(spec.max_rejections)),
            w.scalar("GATE_LEAK", oc.GATE_LEAK), w.scalar("NIS_LOW", oc.NIS_BAND[0]),
            w.scalar("NIS_HIGH", oc.NIS_BAND[1])]
    if spec.harmonics:
        out.append(w.scalar("CMU_REF", spec.cmu_ref))
    if spec.full:
        out += [w.array("FQ", spec.Q), w.array("P_INIT", spec.P0), w.scalar("MEAS_R", spec.R)]
    else:
        out += [w.array("K_STEADY", spec.K), w.scalar("S_STEADY", spec.S)]
    sstate = a["sstate"]
    if np.any(sstate):
        out.append(w.array("SSTATE_INIT", sstate))
    return "".join(out)


def _init(parts: ModelParts, spec: FilterSpec, a: dict[str, np.ndarray]) -> str:
    """``NAME_init``: zero, then what is not zero at rest (the Python observer after ``reset``)."""
    for name in ("buf", "z", "x", "d_cmu", "d_env") + (("m_in", "m_conv") if parts.ints["INTERACTION"] else ()):
        if np.any(a[name]):
            raise ExportError(f"cannot export to C: the model's {name} is not zero at rest")
    lines = ["    for (i = 0; i < DIM_X; i++)", "        st->H[i] = H_FIXED[i];",
             f"    st->pos = {int(a['pos'][0])};"]
    if spec.full:
        lines += ["    for (i = 0; i < DIM_X * DIM_X; i++)", "        st->P[i] = P_INIT[i];"]
    if np.any(a["sstate"]):
        lines += [f"    for (i = 0; i < {a['sstate'].size}; i++)", "        st->sstate[i] = SSTATE_INIT[i];"]
    if spec.harmonics:
        lines.append("    st->since = -1;")
    body = "\n".join(lines)
    return f"""
void PFX_init(PFX_state *st)
{{
    unsigned char *bytes = (unsigned char *)st;
    size_t i;
    for (i = 0; i < sizeof *st; i++)
        bytes[i] = 0;
{body}
}}
"""


def macs(parts: ModelParts, spec: FilterSpec) -> tuple[int, int]:
    """Multiply–adds per step (the loops' trip counts): (model, filter)."""
    i = parts.ints
    n, d = i["N_X"], spec.dim_x
    model = i["N_TAPS"] + 5 * i["N_SEC"] + n * (n + 1) + n + 1
    model += sum(m * (m + 1) + m + 1 for m, *_ in parts.out_stages)
    model += 8 * i["INTERACTION"] + 2 * i["HYST"] + 2 * i["FADE"]
    nnz = int(np.count_nonzero(spec.F))
    filt = nnz + d + n + d + d + n + d           # F ξ, G u, g C, H ξ, the update, C x, h_liftᵀ ξ
    if spec.full:     # F P Fᵀ, P⁻Hᵀ, H P⁻Hᵀ, w, the downdate, the ripple row and term, its basis (angle addition)
        filt += 2 * nnz * d + d * d + d + d + d * d + 2 * (d - spec.ripple_start) + 4 * spec.harmonics
    return model, filt


def _read_template() -> str:
    return resources.files("rtlift.export").joinpath("templates/observer.c.in").read_text(encoding="utf-8")


def export_c(model: HybridModel, out_dir: str | Path, precision: str = "double", gain: str = "full",
             prefix: str = "lift_observer", config: ObserverConfig | None = None, source: str = "model",
             vector_samples: int = 4000) -> CExport:
    """Write ``prefix.h``, ``prefix.c``, ``prefix_test.c`` and ``prefix_vectors.txt`` into ``out_dir``
    for ``model`` and its observer (its stored Q and R unless ``config``)."""
    if precision not in PRECISIONS:
        raise ExportError(f"--precision {precision}: must be 'double' or 'single'")
    if gain not in GAINS:
        raise ExportError(f"--gain {gain}: must be 'steady' or 'full'")
    pfx = _c_identifier(prefix)
    obs = bound_observer(model, config)
    interaction, arrays = kernel_arrays(obs)
    parts = unpack_model(interaction, arrays)
    spec = filter_spec(obs, gain)
    single = precision == "single"
    w = _Writer(single)
    real = "float" if single else "double"
    rl = "#define RL(x) x##f\n#define REXP expf\n#define RSQRT sqrtf\n#define RHUGE HUGE_VALF\n" if single else \
        "#define RL(x) x\n#define REXP exp\n#define RSQRT sqrt\n#define RHUGE HUGE_VAL\n"
    c_text = (f"/* {pfx}.c — generated by rtlift export c ({source}); do not edit. */\n"
              f"#include <math.h>\n#include <stddef.h>\n#include \"{pfx}.h\"\n\ntypedef PFX_real real;\n{rl}\n"
              + _data(w, parts, spec, arrays) + _init(parts, spec, arrays) + "\n" + _read_template())
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        header = out / f"{pfx}.h"
        header.write_text(_header(pfx, parts, spec, real, source), encoding="utf-8")
        src = out / f"{pfx}.c"
        src.write_text(c_text.replace("PFX", pfx), encoding="utf-8")
        cmu, env, dcl, expected = reference_vectors(model, config, spec, vector_samples)
        vectors = out / f"{pfx}_vectors.txt"
        write_vectors(vectors, cmu, env, dcl, expected)
        test = out / f"{pfx}_test.c"
        test.write_text(test_program(pfx, single), encoding="utf-8")
    except OSError as exc:
        raise ExportError(f"{out_dir}: cannot write ({exc.strerror})") from None
    m, f = macs(parts, spec)
    return CExport(header, src, test, vectors, pfx, precision, gain, m, f)
