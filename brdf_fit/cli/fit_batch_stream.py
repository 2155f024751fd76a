"""Streamed ``fit-batch`` runs (``--out-dir``): the run lock, files block by block, and
the launcher of local processes (``--processes``)."""

from __future__ import annotations

import sys

import numpy as np

from brdf_fit.cli._batch_rows import batch_geometry, batch_rows, flag_rows, write_batch_table
from brdf_fit.cli._batch_stream import (
    check_new_run,
    check_out_dir,
    join_run,
    kept_note,
    stream_kw,
    stream_report,
)
from brdf_fit.cli._common import (
    CLIError,
    Outputs,
    check_output_file,
    entry_fix_init,
    read_data,
)
from brdf_fit.cli._processes import child_argv, launch, remove_leftovers_of, stop_children
from brdf_fit.cli._progress import BatchProgress
from brdf_fit.cli.fit_batch_arrays import run_images, run_values
from brdf_fit.core.atomic import write_text_atomic


def run_streamed(args, entry, fix, init) -> int:
    """:func:`_fit_batch_run` holding the output folder's run lock
    (:mod:`brdf_fit.core.runlock`: a second run on the folder stops at once, naming the
    holder), except in a process that joins a multi-process run (its launcher or lead holds the
    folder; on several machines the lock is not taken, as each machine sees its own)."""
    if (getattr(args, "_locked", False) or args.coordinator or args.cluster
            or args.process_id is not None):
        return _fit_batch_run(args, entry, fix, init)
    from brdf_fit.core.runlock import hold

    with hold(check_out_dir(args)):
        args._locked = True
        return _fit_batch_run(args, entry, fix, init)


def _fit_batch_run(args, entry, fix, init) -> int:
    """``fit-batch --out-dir DIR``: the files are read block by block (``--block-size``
    files at a time, default from a 512 MB budget) and fitted by
    :func:`brdf_fit.fitting.stream.fit_stream`, which writes each finished block to DIR
    (``block_*.npz``, ``manifest.json``; ``files.txt`` lists the files in order). A killed run
    restarted with ``--resume`` fits only the blocks not written yet. All files must be
    readable and share one sample count, channel count and sigma-or-not (checked per block;
    the blocks written before a bad file are kept)."""
    import hashlib

    from brdf_fit.fitting.stream import fit_stream

    if args.skip_bad:
        raise CLIError("--skip-bad is not available with --out-dir (every file is needed)")
    if args.processes is not None and args.processes > 1:
        return _fit_batch_processes(args)
    if args.values is not None:
        return run_values(args, entry, fix, init, fit_stream)
    if args.images is not None:
        return run_images(args, entry, fix, init, fit_stream)
    if not args.data:
        raise CLIError("fit-batch needs data files (or --values FILE.npy --geometry FILE.npz "
                       "with --out-dir)")
    shard, sync = join_run(args)
    out = check_out_dir(args)
    if args.out is not None:
        check_output_file(args.out, (".csv", ".json"), "--out")
    check_new_run(args, out)
    paths = list(args.data)
    first = read_data(paths[0])
    first.validate()
    shape = (first.n, first.channels, first.sigma is not None)

    def source(s, e):
        blk = []
        for path in paths[s:e]:
            d = first if path == paths[0] and s == 0 else read_data(path)
            d.validate()
            if (d.n, d.channels, d.sigma is not None) != shape:
                raise CLIError(f"{path}: {d.n} samples, channels {','.join(d.channels)}"
                               f"{', sigma' if d.sigma is not None else ''}; --out-dir needs "
                               f"every file like {paths[0]} ({shape[0]} samples, channels "
                               f"{','.join(shape[1])}{', sigma' if shape[2] else ''})")
            blk.append(d)
        wi, wo = batch_geometry(blk)
        return {"wi": wi, "wo": wo, "values": np.stack([d.value for d in blk]),
                "weight": np.stack([d.weight for d in blk]),
                "sigma": np.stack([d.sigma for d in blk]) if shape[2] else None}

    digest = hashlib.sha256("\n".join(paths).encode()).hexdigest()
    bar = BatchProgress(f"{entry.name}, {len(paths)} file(s) of {first.n} samples",
                        enabled=not args.quiet)
    try:
        res = fit_stream(source, entry.name, out, n_problems=len(paths),
                         meta={"files": digest, "n_files": len(paths)}, progress=bar,
                         **stream_kw(args, fix, init, shard, sync))
    finally:
        bar.close()
    if shard is not None and shard[0] != 0:
        return 0  # the lead (process 0) reports the run
    outs = Outputs(note=kept_note(args))
    outs.write("--out-dir", out / "files.txt",
               lambda: write_text_atomic(out / "files.txt", "\n".join(paths) + "\n"))
    full = res.result()
    rows = batch_rows(paths, full, first.channels)
    flag_rows(rows)
    if args.out is not None:
        outs.write("--out", args.out, lambda: write_batch_table(rows, args.out))
    return stream_report(
        args, entry, res, out, full, f"{len(paths)} file(s)", "files.txt",
        {"files": len(paths),
         "not_converged": [r["file"] for r in rows if not r["converged"]][:100]}, outs)


def _fit_batch_processes(args) -> int:
    """``fit-batch --out-dir DIR --processes N``: N local processes on one machine, joined by
    JAX's multi-process runtime (process 0 hosts the coordinator on a free local port); this
    process launches them, shows the blocks written, and reports the folder when all are done."""
    import socket
    import time

    out = check_out_dir(args)
    check_new_run(args, out)
    if args.coordinator or args.cluster or args.process_id is not None:
        raise CLIError("--processes starts its own processes: not with --coordinator/--cluster")
    if args.images is not None:  # a bad description is reported once, here, not by each child
        from brdf_fit.data import DataError
        from brdf_fit.io.stack import read_stack

        try:
            read_stack(args.images)
        except (DataError, ImportError) as e:
            raise CLIError(str(e)) from None
    with socket.socket() as sock:  # a free port for process 0's coordination service
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    # the report (and its table, --out) is this process's
    argv = child_argv(args, ("--processes", "--out"), ("--resume", "--json", "--quiet"))
    n = args.processes
    before = {int(p.stem.split("_")[1]) for p in out.glob("block_*.npz")} if out.is_dir() else set()
    procs = [launch([*argv, "--quiet", "--coordinator", f"127.0.0.1:{port}",
                     "--num-processes", str(n), "--process-id", str(i)]) for i in range(n)]
    t0 = time.perf_counter()
    tty, last, shown = sys.stderr.isatty(), -1.0, None
    try:
        while any(p.poll() is None for p in procs):
            k = len(list(out.glob("block_*.npz"))) if out.is_dir() else 0
            now = time.perf_counter() - t0
            # a terminal: one line rewritten; a log: a line when a block lands, or every 10 s
            if not args.quiet and (tty or k != shown or now - last >= 10):
                msg = f"fit-batch: {n} processes, {k} block(s) written, {now:.0f} s"
                print("\r" + msg if tty else msg, end="" if tty else "\n", file=sys.stderr,
                      flush=True)
                last, shown = now, k
            time.sleep(0.5)
    except BaseException:  # Ctrl-C or SIGTERM (Terminated): no process outlives this one
        stop_children(procs, folders=[out])
        raise
    finally:
        if not args.quiet and tty:
            print(file=sys.stderr)
    codes = [p.wait() for p in procs]
    remove_leftovers_of(procs, [out])  # a process that crashed
    # 1 is a finished run with some fit not converged (the report below says which); 2 an
    # error, a negative status a signal
    if any(c not in (0, 1) for c in codes):
        bad = ", ".join(f"process {i}: exit status {c}" for i, c in enumerate(codes)
                        if c not in (0, 1))
        raise CLIError(f"{bad}; the blocks written are kept in {args.out_dir}: --resume "
                       "completes the run")
    # every block is written: the report is a resumed run that fits nothing; its counts are
    # this launch's (the blocks the processes wrote are "fitted now", not "already written")
    args.processes, args.resume = None, True
    args._blocks_before = before
    return run_streamed(args, *entry_fix_init(args))
