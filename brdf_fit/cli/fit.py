"""``brdf-fit fit``: one file fitted to one model (several files or models, ``--table``,
are a database run: :mod:`brdf_fit.cli.fit_database`)."""

from __future__ import annotations

import os
import sys

import numpy as np

from brdf_fit.cli._common import (
    CLIError,
    Outputs,
    add_fit_options,
    check_names,
    check_output_file,
    command_line,
    dense_data_of,
    load_registry,
    parse_params,
    positive_float,
    positive_int,
    read_data,
    strict_json,
    use_x64,
)
from brdf_fit.cli._export import export_kind, target_entry, write_export
from brdf_fit.cli._progress import StepProgress
from brdf_fit.cli.check import print_check_table
from brdf_fit.cli.fit_database import run_database
from brdf_fit.data import SUBSAMPLES

#: seconds after which `brdf-fit fit` stops a large (chunked) fit that has not converged
FIT_TIME_LIMIT = 60.0


def param_rows(result, channels) -> list[str]:
    """One line per parameter (per channel for channel parameters): value +- standard error."""
    from brdf_fit.fitting.problem import parameter_entries

    rows = []
    flagged = set(getattr(result, "undetermined", ()))
    for name, j, label, x, se in parameter_entries(result.params, result.stderr, channels):
        note = getattr(result, "stderr_note", {}).get(name)
        note = None if note is None else np.atleast_1d(np.asarray(note, object)).reshape(-1)
        why = str(note[j]) if note is not None and note.size > j else ""
        err = "(fixed)" if name in result.fixed else (
            "" if se is None else
            f"stderr undefined: {why or 'not finite'}" if not np.isfinite(se) else
            f"+- {se:.3g}" + ("  UNDETERMINED" if label in flagged else ""))
        rows.append(f"  {label:<16} {x:12.6g}  {err}")
    return rows


def print_undetermined(labels, indent: str = "  ") -> None:
    """The fit's undetermined entries, with the rule that flags them (or nothing)."""
    from brdf_fit.fitting.problem import UNDETERMINED_RULE

    if labels:
        print(f"{indent}undetermined: {', '.join(labels)} ({UNDETERMINED_RULE}; fix them "
              "(--fix) or measure where they matter)")


def _print_fit(result, data, path: str) -> None:
    print(f"{result.model_name} fitted to {path}: {result.n_samples} samples x "
          f"{data.n_channels} channel(s) ({','.join(data.channels)}), metric {result.metric}"
          + (" (residuals in units of sigma)" if data.sigma is not None else ""))
    print(f"  {'parameter':<16} {'value':>12}  standard error")
    for row in param_rows(result, data.channels):
        print(row)
    if result.at_bound:
        print(f"  at an interval end: {', '.join(result.at_bound)} (a limit, not an optimum; "
              "no standard error)")
    print_undetermined(result.undetermined)
    pairs = result.strongly_correlated()
    if pairs:
        from brdf_fit.fitting.result import STRONG_CORRELATION

        shown = ", ".join(f"{a} ~ {b} ({r:+.4f})" for a, b, r in pairs)
        print(f"  strongly correlated (|r| >= {STRONG_CORRELATION:g}): {shown} (the data "
              "determine a combination of each pair better than either; correlation matrix "
              "in --json)")
    status = "yes" if result.converged else f"NO ({result.message})"
    print(f"converged: {status}; steps: {result.steps}; starts: {result.starts}; "
          f"residual rms: {result.residual_rms:.6g}; time: {result.seconds:.2f} s")
    print_regions(result.regions)
    if result.checks:
        print()
        print_check_table(result.checks)


def print_regions(rows) -> None:
    """The fit against its data by region of the geometry (brdf_fit.fitting.regions), the
    region with the largest rms marked."""
    if not rows:
        return
    rms = [r["rms_log_ratio"] for r in rows]
    worst = int(np.nanargmax(rms)) if np.isfinite(rms).any() else -1
    print("where the misfit is (ln(model/data) by region: rms, and the mean as a factor):")
    for k, r in enumerate(rows):
        stats = ("no samples" if not r["samples"] else
                 f"rms {r['rms_log_ratio']:8.3g}  model {100 * r['mean_factor']:+7.2f}%")
        print(f"  {r['region']:<17} {r['samples']:>8} ({100 * r['share']:5.1f}%)  {stats}"
              + ("  <- largest" if k == worst and len(rows) > 1 else ""))


#: exports up to this size are shown in a report as written
REPORT_EXPORT_MAX_BYTES = 20_000


def _write_report(args, result, data, exported) -> None:
    """``--report``: the fit's HTML page (:func:`brdf_fit.report.fit_report`), whole or not at
    all; a MERL file's dense table is read again for its renders and slice."""
    from brdf_fit.core.atomic import write_text_atomic
    from brdf_fit.report import fit_report

    export = None
    if exported is not None:
        export = {**exported, "path": args.export}
        if os.path.getsize(args.export) <= REPORT_EXPORT_MAX_BYTES:
            with open(args.export, encoding="utf-8") as fh:
                export["text"] = fh.read()
    page = fit_report(result, data, source=args.data, table=dense_data_of(data, args.data),
                      export=export, command=command_line(args))
    write_text_atomic(args.report, page)


def run(args) -> int:
    use_x64()
    models = [m.strip() for m in args.model.split(",") if m.strip()]
    if len(args.data) > 1 or len(models) > 1 or args.table is not None or args.shard:
        if args.report is not None and args.shard:
            raise CLIError("--report is written by the run that assembles the table, not by "
                           "one --shard of it")
        return run_database(args, models)
    if args.processes is not None:
        raise CLIError("--processes shares a database run (several files or models, --table)")
    args.data = args.data[0]
    from brdf_fit.fitting.single import fit

    reg = load_registry()
    entry = target_entry(reg, args.model, args.target)  # fails before the data are read
    kind = export_kind(args.export, args.target)
    if args.report is not None:
        check_output_file(args.report, (".html",), "--report")
    fix = parse_params(args.fix, entry, "--fix")
    init = parse_params(args.init, entry, "--init")
    both = sorted(set(fix) & set(init))
    if both:
        raise CLIError(f"parameter(s) {', '.join(both)} given both --fix and --init")
    checks = check_names(args.check)
    if args.multistart < 1:
        raise CLIError(f"--multistart must be >= 1, got {args.multistart}")
    data = read_data(args.data)
    if args.max_samples is not None:
        if args.max_samples < 1:
            raise CLIError(f"--max-samples must be >= 1, got {args.max_samples}")
        data = data.subsample(args.max_samples, args.seed, args.subsample)
    if not args.quiet:  # one status line: a first fit spends most of its time compiling
        print(f"fitting {entry.name} to {data.n} samples x {data.n_channels} channels "
              f"(metric {args.metric}, {args.multistart} start(s)) ...", file=sys.stderr,
              flush=True)
    progress = StepProgress(data.n, enabled=not args.quiet)
    try:
        result = fit(data, entry.name, fix=fix, init=init, metric=args.metric,
                     solver=args.solver, cos_weight=args.cos_weight,
                     max_zenith_deg=args.max_zenith_deg, multistart=args.multistart,
                     seed=args.seed, max_steps=args.max_steps, checks=checks, guess=args.guess,
                     time_limit=args.time_limit, progress=progress)
    finally:
        progress.close()
    result.regions = result.residuals_by_region(data)
    exported = []
    outs = Outputs(note="the fit is printed instead")  # nothing computed is lost to a write
    if kind is not None:
        outs.write("--export", args.export, lambda: exported.append(write_export(
            kind, args.export, entry.name, result.params, data,
            name=os.path.splitext(os.path.basename(args.data))[0])),
            also=(CLIError,) if kind in ("blender", "openpbr") else ())  # e.g. a .blend
        # without Blender, a model the target does not hold: the fit is printed all the same
    exported = exported[0] if exported else None
    if args.report is not None:
        outs.write("--report", args.report, lambda: _write_report(args, result, data, exported))
    if args.json:
        doc = result.to_dict()
        if exported is not None:
            doc["export"] = exported
        print(strict_json(outs.annotate(doc)))
    else:
        _print_fit(result, data, args.data)
        if exported is not None:
            err = exported["error"]
            print(f"export: {exported['target']} {exported['method']} "
                  + ("(not verified)" if err is None else f"(round-trip error {err:.3g})")
                  + f": {exported['note']}")
            print(f"wrote {args.export}")
        if args.report is not None and args.report in outs.written:
            print(f"wrote {args.report}")
    if outs.failed:
        return outs.status()
    failed = [c for c in result.checks if not c.ok]
    return 0 if result.converged and not failed else 1


def add_parser(sub) -> None:
    f = sub.add_parser("fit", help="fit a registry model to measured data (or many files to "
                                   "several models: --table)")
    f.add_argument("data", nargs="+",
                   help="data file: .csv, .npz (or its .json sidecar), MERL .binary, RGL "
                        ".bsdf; with --table any number of files and folders (a database run)")
    add_fit_options(f, what="drop", models="registry name (see 'brdf-fit models'); with --table "
                                        "a comma-separated list")
    f.add_argument("--solver", default="lm",
                   help="lm (default), levenberg-marquardt, gauss-newton, gauss-newton-plain, "
                        "dogleg")
    f.add_argument("--multistart", type=positive_int, default=1, metavar="K",
                   help="K starts (the first from --init, the others perturbed); best loss wins")
    f.add_argument("--seed", type=int, default=0, help="seed of multistart and --max-samples")
    f.add_argument("--max-samples", type=positive_int, default=None, metavar="N",
                   help="fit a seeded random subset of N samples (e.g. of a MERL file)")
    f.add_argument("--subsample", choices=SUBSAMPLES, default="uniform",
                   help="how --max-samples draws: a simple random sample (default), or one "
                        "stratified by the half and difference angles, each stratum its "
                        "proportional share")
    f.add_argument("--time-limit", type=positive_float, default=FIT_TIME_LIMIT, metavar="S",
                   help="stop a fit of large data (solved in chunks: a whole MERL file) that "
                        f"has not converged after S seconds, reported as not converged "
                        f"(default {FIT_TIME_LIMIT:g})")
    f.add_argument("--check", action="append", metavar="NAME",
                   help="run this check on the fitted model (repeatable)")
    f.add_argument("--target", default=None, metavar="T",
                   help="mitsuba, gltf, blender or openpbr: fit a model the target holds as "
                        "fitted (a native entry; a bare name like roughplastic means "
                        "mitsuba-roughplastic, principled with --target blender "
                        "blender-principled, surface with --target openpbr openpbr-surface)")
    f.add_argument("--export", default=None, metavar="OUT",
                   help="write the fitted model for a renderer: .xml (Mitsuba 3 scene with one "
                        "bsdf) or .gltf (glTF 2.0 material), checked by round trip on the data; "
                        ".py (a Blender script making a Principled BSDF material), .blend "
                        "(needs Blender's Python: make blender) or .mtlx (a MaterialX document "
                        "of an OpenPBR Surface material)")
    f.add_argument("--report", default=None, metavar="OUT.html",
                   help="one self-contained HTML page: parameters with 95%% intervals, where "
                        "the misfit is, the fit rendered (MERL data also rendered from "
                        "themselves, with FLIP between the two), slices, the command; for a "
                        "database run (--table): every model's error on every material, the "
                        "figure, each material's best fit rendered")
    db = f.add_argument_group("a database run (many files x models, one table)")
    db.add_argument("--table", default=None, metavar="OUT.csv",
                    help="fit every file to every --model and write the table (CSV, and JSON "
                         "beside it: parameters, standard errors, rel. RMS and the published "
                         "error measures, time) and its figure (.png); each finished pair is "
                         "kept in OUT.csv.parts/, so the same command resumes a stopped run")
    db.add_argument("--processes", type=positive_int, default=None, metavar="N",
                    help="share the pairs among N local processes")
    db.add_argument("--shard", default=None, metavar="I/N",
                    help="fit only pairs I, I+N, ... (one machine of several on a shared "
                         "folder; a run without --shard then writes the table)")
    f.add_argument("--json", action="store_true", help="print FitResult.to_dict() (a database "
                                                       "run: the table's JSON)")
    f.add_argument("--quiet", action="store_true", help="no status line on stderr")
    f.set_defaults(func=run)
