"""``rtlift export``: the model for use outside Python — ``c`` (a C99 module of the model and its
observer, :mod:`rtlift.export.c_module`) and ``mat`` (a MATLAB file, :mod:`rtlift.export.mat`)."""

from __future__ import annotations

import argparse

from rtlift.core.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "export", help="the model as C for a firmware (c) or as a MATLAB file (mat)",
        description="Export a model file: 'c' writes the model and its Kalman observer as one C99 "
                    "module (NAME.h, NAME.c: static const parameters, fixed-size state, no malloc) with "
                    "a test program and the vector it must reproduce; 'mat' writes the model's matrices "
                    "for MATLAB.")
    sub = p.add_subparsers(dest="target", metavar="TARGET", parser_class=type(p))
    sub.required = True
    c = sub.add_parser("c", help="a C99 module of the model and its observer",
                       description="Write NAME.h, NAME.c, NAME_test.c and NAME_vectors.txt into DIR: "
                                   "NAME_init, NAME_step (estimate, model lift, innovation, NIS per sample) "
                                   "and NAME_model_step (the model alone), equal to the Python observer.")
    c.add_argument("--model", required=True, metavar="MODEL.json", help="model file with observer settings")
    c.add_argument("--out", required=True, metavar="DIR", help="folder to write into (created)")
    c.add_argument("--precision", choices=("double", "single"), default="double",
                   help="the C type of the state and parameters (default double; single for an FPU "
                        "without double, e.g. a Cortex-M4F)")
    c.add_argument("--gain", choices=("steady", "full"), default="full",
                   help="full: the covariance recursion as in Python (default); steady: the steady-state "
                        "Kalman gain computed now, no covariance in the step (ripple and gain-error "
                        "states left out)")
    c.add_argument("--prefix", default="lift_observer", metavar="NAME",
                   help="file and symbol prefix (a C identifier; default lift_observer)")
    c.set_defaults(func=run_c)
    m = sub.add_parser("mat", help="the model's matrices as a MATLAB .mat file",
                       description="Write the Wiener LTI (A, B, C, D), the static map, the kernel and φ, "
                                   "the high-pass sections and the observer's Q and R (scipy.io.savemat).")
    m.add_argument("--model", required=True, metavar="MODEL.json", help="model file")
    m.add_argument("--out", required=True, metavar="M.mat", help="file to write")
    m.set_defaults(func=run_mat)


def _lift_model(path: str):
    from rtlift.api import is_generic, load

    model = load(path)
    if is_generic(model):
        raise UserError(f"{path}: a generic t,u,y model; export takes a lift model")
    return model


def run_c(args: argparse.Namespace) -> int:
    from rtlift.export.c_module import export_c

    model = _lift_model(args.model)
    out = export_c(model, args.out, precision=args.precision, gain=args.gain, prefix=args.prefix,
                   source=args.model)
    print(f"wrote {out.header}, {out.source}, {out.test}, {out.vectors}")
    print(f"{args.precision} precision, {args.gain} gain: {out.macs} multiply-adds per step "
          f"(model {out.macs_model}, filter {out.macs_filter})")
    print(f"check: cd {args.out} && cc -std=c99 -O2 {out.prefix}.c {out.prefix}_test.c -lm -o {out.prefix}_test "
          f"&& ./{out.prefix}_test {out.prefix}_vectors.txt")
    return 0


def run_mat(args: argparse.Namespace) -> int:
    from rtlift.export.mat import export_mat

    data = export_mat(_lift_model(args.model), args.out)
    n = data["A"].shape[0]
    extra = f", observer Q {data['observer_Q'].shape[0]}x{data['observer_Q'].shape[0]} and R" \
        if "observer_Q" in data else " (no observer settings in the model file)"
    print(f"wrote {args.out}: A {n}x{n}, B, C, D, static map ({data['static_map_form']}), "
          f"kernel {data['kernel'].size} taps, {data['highpass_sos'].shape[0]} high-pass sections{extra}")
    return 0
