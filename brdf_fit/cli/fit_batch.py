"""``brdf-fit fit-batch``: one model fitted to many files at once (in memory), or streamed
to a folder (:mod:`brdf_fit.cli.fit_batch_stream`)."""

from __future__ import annotations

import numpy as np

from brdf_fit.cli._batch_rows import (
    batch_geometry,
    batch_rows,
    flag_rows,
    note_text,
    read_many,
    write_batch_table,
)
from brdf_fit.cli._common import (
    CLIError,
    Outputs,
    add_fit_options,
    check_output_file,
    entry_fix_init,
    fmt,
    positive_int,
    strict_json,
    use_x64,
)
from brdf_fit.cli._progress import BatchProgress
from brdf_fit.cli.fit_batch_stream import run_streamed


def run(args) -> int:
    use_x64()
    from brdf_fit.fitting.batch import fit_batch

    entry, fix, init = entry_fix_init(args)
    if args.values is not None and args.out_dir is None:
        raise CLIError("--values needs --out-dir (the streamed path writes the maps there)")
    if args.images is not None and args.out_dir is None:
        raise CLIError("--images needs --out-dir (the streamed path writes the maps there)")
    if args.out_dir is None and not args.data:
        raise CLIError("fit-batch needs data files")
    if args.out_dir is not None:
        return run_streamed(args, entry, fix, init)
    if args.resume or args.block_size is not None:
        raise CLIError("--resume and --block-size need --out-dir (the streamed path)")
    if (args.processes or args.coordinator or args.cluster or args.num_processes
            or args.process_id is not None):
        raise CLIError("several processes need --out-dir (the streamed path)")
    if args.out is not None:
        check_output_file(args.out, (".csv", ".json"), "--out")
    good, bad = read_many(args.data, args.skip_bad)
    # one batch per (sample count, channels, sigma or not): fit_batch stacks equal shapes
    groups: dict = {}
    for path, d in good:
        groups.setdefault((d.n, d.channels, d.sigma is not None), []).append((path, d))
    rows = []
    for (n, channels, has_sigma), items in groups.items():
        paths = [p for p, _ in items]
        label = f"{entry.name}, {len(items)} file(s) of {n} samples"
        progress = BatchProgress(label, enabled=not args.quiet)
        try:
            res = fit_batch(
                *batch_geometry([d for _, d in items]),
                np.stack([d.value for _, d in items]), entry.name,
                weight=np.stack([d.weight for _, d in items]),
                sigma=np.stack([d.sigma for _, d in items]) if has_sigma else None,
                fix=fix, init=init, metric=args.metric, cos_weight=args.cos_weight,
                max_zenith_deg=args.max_zenith_deg, max_steps=args.max_steps,
                guess=args.guess, progress=progress)
        finally:
            progress.close()
        rows += batch_rows(paths, res, channels)
    flag_rows(rows)
    outs = Outputs()  # the rows are printed whether or not --out could be written
    if args.out is not None:
        outs.write("--out", args.out, lambda: write_batch_table(rows, args.out))
    if args.json:
        print(strict_json(outs.annotate({"model": entry.name, "results": rows,
                                        "unreadable": bad})))
    else:
        names = [n for n in entry.param_names]
        print(f"{entry.name} fitted to {len(rows)} file(s), metric {args.metric}")
        head = f"  {'file':<28} {'conv':>4} {'steps':>5} {'rms':>10}  " + "  ".join(names)
        print(head)
        for r in rows:
            vals = "  ".join(fmt(r["params"][k]) for k in names)
            flag = "" if not r["at_bound"] else f"  (at bound: {', '.join(r['at_bound'])})"
            other = [f for f in r["flags"] if f not in ("not converged", "at bound")]
            if other:
                flag += f"  ({'; '.join(other)})"
            unid = [k for k, v in r["stderr_note"].items() if "not identifiable" in note_text(v)]
            if unid:
                flag += f"  (stderr undefined, not identifiable: {', '.join(unid)})"
            print(f"  {r['file'][-28:]:<28} {'yes' if r['converged'] else 'NO':>4} "
                  f"{r['steps']:>5} {r['residual_rms']:10.4g}  {vals}{flag}")
        for msg in bad:
            print(f"  skipped: {msg}")
        n_und = sum(bool(r["undetermined"]) for r in rows)
        if n_und:
            from brdf_fit.fitting.problem import UNDETERMINED_RULE

            print(f"  {n_und} of {len(rows)} fit(s) with undetermined parameters "
                  f"({UNDETERMINED_RULE})")
        for path in outs.written:
            print(f"wrote {path}")
    return outs.status(0 if all(r["converged"] for r in rows) and not bad else 1)


def add_parser(sub) -> None:
    fb = sub.add_parser("fit-batch", help="fit one registry model to many data files at once "
                                          "(brdf_fit.fit_batch)")
    fb.add_argument("data", nargs="*", help="data files (.csv, .npz, MERL .binary, RGL .bsdf); "
                                            "files with equal sample counts are fitted in one "
                                            "batch")
    fb.add_argument("--values", default=None, metavar="FILE.npy",
                    help="instead of files, with --out-dir: an (N, M, C) or (N, M) array of "
                         "N problems (memory-mapped), on one geometry (--geometry); writes "
                         "parameter maps DIR/maps/*.npy")
    fb.add_argument("--images", default=None, metavar="STACK.json",
                    help="instead of files, with --out-dir: an image stack (a JSON description "
                         "of M images, .exr or .npy, and each one's light and view direction; "
                         "brdf_fit.io.stack), one problem per texel; writes maps DIR/maps/"
                         "*.npy and *.exr of the image's size")
    fb.add_argument("--geometry", default=None, metavar="FILE.npz",
                    help="with --values: arrays wi and wo, (M, 3) each, in the local frame")
    add_fit_options(fb, what="mask")
    fb.add_argument("--skip-bad", action="store_true",
                    help="fit the readable files and list the unreadable ones (default: stop)")
    fb.add_argument("--out", default=None, metavar="FILE",
                    help="write one row per file to FILE (.csv or .json)")
    fb.add_argument("--json", action="store_true", help="print the per-file results as JSON")
    fb.add_argument("--quiet", action="store_true", help="no progress bar")
    fb.add_argument("--out-dir", default=None, metavar="DIR",
                    help="stream: read and fit the files block by block, writing each "
                         "finished block to DIR (block_*.npz, manifest.json); for many files")
    fb.add_argument("--block-size", type=positive_int, default=None, metavar="N",
                    help="with --out-dir: files per block (default: from a 512 MB budget)")
    fb.add_argument("--resume", action="store_true",
                    help="with --out-dir: continue a killed run, fitting only the blocks not "
                         "written yet")
    mp = fb.add_argument_group("several processes (with --out-dir; JAX's multi-process "
                               "runtime, brdf_fit.fitting.distributed)")
    mp.add_argument("--processes", type=positive_int, default=None, metavar="N",
                    help="start N local processes that share the blocks (one machine)")
    mp.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                    help="join a multi-process run whose process 0 listens at HOST:PORT "
                         "(with --num-processes and --process-id)")
    mp.add_argument("--num-processes", type=positive_int, default=None, metavar="N")
    mp.add_argument("--process-id", type=int, default=None, metavar="I")
    mp.add_argument("--cluster", action="store_true",
                    help="join a multi-process run described by the cluster's environment "
                         "(SLURM, Open MPI: read by jax.distributed)")
    mp.add_argument("--join-timeout", type=float, default=None, metavar="S",
                    help="seconds to reach the coordinator before giving up (default 60)")
    fb.set_defaults(func=run)
