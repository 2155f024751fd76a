"""What every streamed ``fit-batch`` run shares (``--out-dir``): the folder checked, the
multi-process run joined, fit_stream's keywords, and the report."""

from __future__ import annotations

import numpy as np

from brdf_fit.cli._common import CLIError, check_output_dir, strict_json


def check_out_dir(args):
    """``--out-dir`` as a path (the folder created), refused before any work when it names a
    file, its parent folder does not exist, or it cannot be created or written
    (:func:`~brdf_fit.cli._common.check_output_dir`)."""
    import pathlib

    out = pathlib.Path(args.out_dir)
    parent = out.parent if str(out.parent) else pathlib.Path(".")
    if not out.exists() and parent.exists() and not parent.is_dir():
        raise CLIError(f"{args.out_dir}: cannot write: {str(parent)!r} is a file, not a folder")
    if not out.exists() and not parent.is_dir():
        raise CLIError(f"{args.out_dir}: cannot write: folder {str(parent)!r} does not exist")
    # an existing file refused, the folder created (one under /proc is refused), writable
    check_output_dir(args.out_dir, "--out-dir")
    return out


def check_new_run(args, out) -> None:
    """A folder holding a previous run (its manifest) is refused without ``--resume``; a process
    joining a multi-process run is exempt (its lead, process 0, settles the folder)."""
    if (out / "manifest.json").exists() and not args.resume and not (
            args.coordinator or args.cluster):
        raise CLIError(f"{args.out_dir}: holds a previous run; --resume continues it (or "
                       "choose a new folder)")


def join_run(args):
    """``(shard, sync)`` for fit_stream: this process's place in a multi-process run (joined
    here, before any JAX computation), or ``(None, None)`` for a single process."""
    given = [args.coordinator is not None, args.num_processes is not None,
             args.process_id is not None]
    if not (any(given) or args.cluster):
        return None, None
    if any(given) and args.cluster:
        raise CLIError("--cluster reads the run from the environment: not with --coordinator")
    if any(given) and not all(given):
        raise CLIError("--coordinator, --num-processes and --process-id go together")
    from brdf_fit.fitting import distributed

    kw = {} if args.join_timeout is None else {"timeout_s": args.join_timeout}
    index, count = distributed.initialize(args.coordinator, args.num_processes,
                                          args.process_id, **kw)
    return (index, count), distributed.barrier


def stream_kw(args, fix, init, shard, sync) -> dict:
    """fit_stream's keywords from fit-batch's options, the same for files and value arrays (a
    process of a multi-process run always resumes: the lead settled the folder)."""
    return {"block_size": args.block_size, "resume": args.resume or shard is not None,
            "shard": shard, "sync": sync, "fix": fix, "init": init, "metric": args.metric,
            "cos_weight": args.cos_weight, "max_zenith_deg": args.max_zenith_deg,
            "max_steps": args.max_steps, "guess": args.guess}


def kept_note(args) -> str:
    """What a streamed run keeps when an output it writes at the end cannot be written."""
    return (f"the fitted blocks are kept in {args.out_dir}: the same command with --resume "
            "writes the outputs")


def stream_report(args, entry, res, out, full, what, wrote, extra, outs,
                  measured=None) -> int:
    """The summary of a streamed fit-batch run (JSON or two lines) and its exit status: 0
    when every problem converged, else 1. ``what``: the problems in words; ``wrote``: what the
    folder holds besides the blocks and the manifest; ``extra``: the JSON's own fields;
    ``outs``: the :class:`~brdf_fit.cli._common.Outputs` written at the end (the per-file table
    of ``--out``, the maps), reported; ``measured``: the problems that count (a mask; default
    all)."""
    before = getattr(args, "_blocks_before", None)
    if before is not None:  # a --processes launch: what its processes wrote is fitted now
        done = sorted({*res.fitted, *res.skipped})
        res.fitted = [k for k in done if k not in before]
        res.skipped = [k for k in done if k in before]
    conv = np.asarray(full.converged)
    conv = float(np.mean(conv if measured is None else conv[measured])) if (
        measured is None or np.any(measured)) else 0.0
    summary = {"model": entry.name, "out_dir": str(out), **extra, "blocks": res.n_blocks,
               "block_size": res.block_size, "fitted": res.fitted, "skipped": res.skipped,
               "converged": conv, "seconds": round(res.seconds, 3)}
    if args.json:
        print(strict_json(outs.annotate(summary)))
    else:
        print(f"{entry.name} fitted to {what}, metric {args.metric}, in "
              f"{res.n_blocks} block(s) of {res.block_size} ({len(res.fitted)} fitted now, "
              f"{len(res.skipped)} already written); converged {100 * conv:.2f}%")
        print(f"wrote {out}/ (block_*.npz, manifest.json"
              + (f", {wrote})" if not outs.failed else ")"))
        if getattr(args, "out", None) is not None and args.out in outs.written:
            print(f"wrote {args.out}")
    return outs.status(0 if conv == 1.0 else 1)
