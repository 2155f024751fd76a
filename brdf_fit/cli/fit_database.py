"""``brdf-fit fit FILES --model A,B --table T.csv``: a database run, every file fitted to
every model, kept pair by pair, resumable, over several processes."""

from __future__ import annotations

import os
import sys

import numpy as np

from brdf_fit.cli._common import (
    CLIError,
    Outputs,
    Terminated,
    check_output_file,
    command_line,
    load_registry,
    parse_params,
    strict_json,
)
from brdf_fit.cli._processes import child_argv, launch, remove_leftovers_of, stop_children

#: data file extensions a folder given to `fit` is searched for
_DATA_EXTS = (".binary", ".bsdf", ".csv", ".npz")


def _database_files(items, exclude=()) -> list[str]:
    """The data files of ``fit``'s positional arguments: a folder stands for its data files
    (:data:`_DATA_EXTS`, sorted) but the ``exclude`` files (the run's own table, which may be
    written into the folder it reads); a file named twice is fitted once."""
    skip = {os.path.abspath(x) for x in exclude}
    out = []
    for item in items:
        if os.path.isdir(item):
            found = sorted(os.path.join(item, n) for n in os.listdir(item)
                           if n.lower().endswith(_DATA_EXTS)
                           and os.path.abspath(os.path.join(item, n)) not in skip)
            if not found:
                raise CLIError(f"{item}: a folder with no data file ({', '.join(_DATA_EXTS)})")
            out += found
        else:
            out.append(item)
    return list(dict.fromkeys(out))


def _parse_shard(text: str) -> tuple[int, int]:
    try:
        i, n = (int(x) for x in text.split("/"))
    except ValueError:
        raise CLIError(f"--shard must be I/N (e.g. 0/2), got {text!r}") from None
    if not (n >= 1 and 0 <= i < n):
        raise CLIError(f"--shard {text}: need 0 <= I < N")
    return i, n


def run_database(args, models) -> int:
    """:func:`_fit_database_run` holding the run lock of the table's parts folder
    (:mod:`brdf_fit.core.runlock`), except for one shard of a run (``--shard``: the launcher
    holds it, or the machines of a shared folder each run their own share)."""
    from brdf_fit.fitting.database import PARTS_SUFFIX

    parent = os.path.dirname(os.path.abspath(args.table)) if args.table else None
    if args.shard or args.table is None or not os.path.isdir(parent):
        return _fit_database_run(args, models)  # (a missing folder is its error to report)
    from brdf_fit.core.runlock import hold

    with hold(args.table + PARTS_SUFFIX):
        return _fit_database_run(args, models)


def _fit_database_run(args, models) -> int:
    """``brdf-fit fit FILES --model A,B --table OUT.csv``: every file fitted to every model
    (:mod:`brdf_fit.fitting.database`), kept pair by pair, resumable, over several processes
    with ``--processes N`` (or ``--shard I/N`` per machine on a shared folder)."""
    import time

    from brdf_fit.fitting import database

    if args.table is None:
        raise CLIError("several files or models: name the table to write with --table OUT.csv")
    if not args.table.lower().endswith(".csv"):
        raise CLIError(f"--table {args.table}: the table is a .csv file (its .json is written "
                       "beside it)")
    for flag, given in (("--export", args.export), ("--target", args.target),
                        ("--check", args.check)):
        if given:
            raise CLIError(f"{flag} is for one fit; a database run writes a table")
    if (args.fix or args.init) and len(models) > 1:
        raise CLIError("--fix and --init name one model's parameters: give one --model with "
                       "them")
    check_output_file(args.table, (".csv",), "--table")
    if args.report is not None:
        check_output_file(args.report, (".html",), "--report")
    reg = load_registry()
    entries = [reg.get(m) for m in models]  # an unknown name fails before any file is read
    files = _database_files(args.data, exclude=(args.table,))
    fix = parse_params(args.fix, entries[0], "--fix") if args.fix else {}
    init = parse_params(args.init, entries[0], "--init") if args.init else {}
    options = {"metric": args.metric, "cos_weight": args.cos_weight,
               "max_zenith_deg": args.max_zenith_deg, "multistart": args.multistart,
               "seed": args.seed, "max_steps": args.max_steps, "guess": args.guess,
               "time_limit": args.time_limit,
               "fix": {k: np.asarray(v).tolist() for k, v in fix.items()},
               "init": {k: np.asarray(v).tolist() for k, v in init.items()}}
    if args.max_samples is not None:  # part of each pair's identity, not a fit() option
        options["max_samples"] = args.max_samples
        if args.subsample != "uniform":  # (absent when uniform: tables made before keep theirs)
            options["subsample"] = args.subsample
    folder = args.table + database.PARTS_SUFFIX
    names = [e.name for e in entries]
    shard = _parse_shard(args.shard) if args.shard else None
    if shard is not None and args.processes is not None:
        raise CLIError("--processes starts its own shards: not with --shard")
    before = None
    if args.processes is not None and args.processes > 1:
        before = database.count_finished(files, names, folder, options)
        _database_processes(args)
    max_samples = args.max_samples

    def reader(path):
        from brdf_fit import io

        data = io.read(path)  # a DataError is that file's failure, reported in the table's run
        if max_samples is not None:
            data = data.subsample(max_samples, args.seed, args.subsample)
        return data

    fit_options = {**{k: v for k, v in options.items() if k not in ("max_samples", "subsample")},
                   "fix": fix, "init": init}

    def progress(done, total, text):
        if not args.quiet:
            print(f"[{done}/{total}] {text}", file=sys.stderr, flush=True)

    t0 = time.perf_counter()
    try:
        run = database.fit_database(files, names, folder, fit_options=fit_options,
                                    identity=options, shard=shard, progress=progress,
                                    reader=reader)
    except (KeyboardInterrupt, Terminated) as e:
        kept = database.count_finished(files, names, folder, options)
        print(f"brdf-fit: {'interrupted' if isinstance(e, KeyboardInterrupt) else 'terminated'}"
              f": {kept} finished pair(s) kept in {folder}; the same command continues the run",
              file=sys.stderr)
        return 130 if isinstance(e, KeyboardInterrupt) else 143
    if before is not None:  # the processes fitted what this run found done, but `before`
        run.fitted_now += run.already_done - before
        run.already_done = before
    if shard is not None:  # one share of a run: the table is assembled by a run without it
        if not args.quiet:
            print(f"shard {args.shard}: {run.fitted_now} fitted now, {run.already_done} done "
                  f"before, {run.failed} failed", file=sys.stderr)
        return 0 if not run.failed else 1
    meta = {"files": files, "models": names, "options": options,
            "pairs": run.total, "finished": len(run.rows), "failures": run.failures}
    outs = Outputs(note=f"the finished pairs are kept in {folder}: the same command writes "
                        "the table without fitting them again")
    if run.unsaved:  # a full disk while fitting: those rows are printed, but not kept
        outs.note = "the rows are printed instead"
        outs.failed.append(f"{len(run.unsaved)} finished pair(s) could not be kept in {folder} "
                           f"(first: {run.unsaved[0]}; a later run fits them again)")
    outs.write("--table", args.table, lambda: database.write_table(args.table, run.rows, meta))
    figure = os.path.splitext(args.table)[0] + ".png"
    try:
        from brdf_fit.plot import database_errors

        if run.rows:
            outs.figure("--table", figure, database_errors(run.rows))
    except ImportError:
        pass  # matplotlib is an extra: the table stands without its figure
    if args.report is not None and run.rows:
        outs.write("--report", args.report, lambda: _write_database_report(args, run, meta))
    written = outs.written
    seconds = time.perf_counter() - t0
    not_conv = [f"{r['material']} {r['model']}" for r in run.rows if not r["converged"]]
    if args.json:
        print(strict_json(outs.annotate({
            **meta, "fitted_now": run.fitted_now, "already_done": run.already_done,
            "failed": run.failed, "not_converged": not_conv, "written": written,
            "seconds": round(seconds, 3), "rows": run.rows}), indent=1))
    else:
        _print_database(run, names)
        print(f"{run.fitted_now} fitted now + {run.already_done} done before + {run.failed} "
              f"failed = {run.total} pairs ({len(files)} files x {len(names)} models) in "
              f"{seconds:.1f} s; wrote {', '.join(written) or 'nothing'}")
        for f in run.failures:
            print(f"  failed: {f}")
        if not_conv:
            print(f"  not converged: {', '.join(not_conv)}")
    return outs.status(0 if not run.failed and not not_conv else 1)


def _print_database(run, models) -> None:
    """The relative RMS radiance error per material (rows) and model (columns)."""
    by = {(r["material"], r["model"]): r for r in run.rows}
    materials = list(dict.fromkeys(r["material"] for r in run.rows))
    width = max([8, *(len(m) for m in materials)])
    print(f"{'rel. RMS':<{width}} " + " ".join(f"{m:>14}" for m in models))
    for mat in materials:
        cells = []
        for m in models:
            r = by.get((mat, m))
            cells.append("-" if r is None else
                         f"{r['errors']['rel_rms']:.4g}{'' if r['converged'] else '*'}")
        print(f"{mat:<{width}} " + " ".join(f"{c:>14}" for c in cells))
    if any(not r["converged"] for r in run.rows):
        print("(* not converged)")


def _write_database_report(args, run, meta) -> None:
    """``--report``: the run's HTML page (:func:`brdf_fit.report.database_report`)."""
    from brdf_fit.core.atomic import write_text_atomic
    from brdf_fit.report import database_report

    write_text_atomic(args.report, database_report(run.rows, meta, table=args.table,
                                                   command=command_line(args)))


def _database_processes(args) -> None:
    """``--processes N``: N local processes, each fitting every N-th pair (``--shard I/N``);
    returns when all have ended (the caller then assembles the table, fitting whatever a
    process could not finish). Ctrl-C stops them all."""

    from brdf_fit.fitting.database import PARTS_SUFFIX

    argv = child_argv(args, ("--processes", "--report"), ("--json", "--quiet"))
    n = args.processes
    procs = [launch([*argv, "--shard", f"{i}/{n}", *(["--quiet"] if args.quiet else [])])
             for i in range(n)]
    parts = args.table + PARTS_SUFFIX
    try:
        for p in procs:
            p.wait()
    except BaseException:  # Ctrl-C or SIGTERM (Terminated): no process outlives this one
        stop_children(procs, folders=[parts])
        raise
    remove_leftovers_of(procs, [parts])  # a process that crashed
