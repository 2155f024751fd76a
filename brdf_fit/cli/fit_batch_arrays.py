"""Streamed ``fit-batch`` runs on arrays: ``--values`` (N problems on one geometry) and
``--images`` (one problem per texel of an image stack)."""

from __future__ import annotations

import json
import pathlib
import sys

import numpy as np

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
)
from brdf_fit.cli._progress import BatchProgress


def run_values(args, entry, fix, init, fit_stream) -> int:
    """``fit-batch --values V.npy --geometry G.npz --out-dir DIR``: N problems on one shared
    geometry, streamed from a memory-mapped array; the parameter maps (``maps/params_NAME.npy``
    (N, ...), ``maps/stderr_NAME.npy``, ``maps/converged.npy``, ``maps/undetermined_NAME.npy``)
    are written when every block is."""

    if args.data:
        raise CLIError("give data files or --values, not both")
    if args.geometry is None:
        raise CLIError("--values needs --geometry FILE.npz (arrays wi and wo, (M, 3))")
    try:
        values = np.load(args.values, mmap_mode="r")
    except (OSError, ValueError) as e:
        raise CLIError(f"{args.values}: cannot read a .npy array ({e})") from None
    from brdf_fit.data import DataError, check_values, unit_directions

    if values.dtype.kind != "f":
        raise CLIError(f"{args.values}: dtype {values.dtype}, expected a float array of BRDF "
                       "values")
    try:
        with np.load(args.geometry, allow_pickle=False) as g:
            wi, wo = np.asarray(g["wi"], float), np.asarray(g["wo"], float)
    except (OSError, ValueError, KeyError, AttributeError, TypeError) as e:
        raise CLIError(f"{args.geometry}: needs a .npz with arrays wi and wo, (M, 3) ({e})"
                       ) from None
    if values.ndim not in (2, 3) or wi.shape != (values.shape[1], 3) or wo.shape != wi.shape:
        raise CLIError(f"{args.values}: shape {values.shape} with wi {wi.shape}, wo "
                       f"{wo.shape}: expected (N, M[, C]) values and (M, 3) directions")
    try:  # the rule of image stacks: normalised, zero-length and below-horizon refused
        wi = unit_directions(wi, f"{args.geometry}: wi")
        wo = unit_directions(wo, f"{args.geometry}: wo")
        check_values(values, args.values)
    except DataError as e:
        raise CLIError(str(e)) from None
    out = check_out_dir(args)
    check_new_run(args, out)
    shard, sync = join_run(args)
    bar = BatchProgress(f"{entry.name}, {values.shape[0]} problems of {values.shape[1]} samples",
                        enabled=not args.quiet)
    try:
        res = fit_stream(values, entry.name, out, wi=wi, wo=wo,
                         meta={"values": str(args.values), "shape": values.shape}, progress=bar,
                         **stream_kw(args, fix, init, shard, sync))
    finally:
        bar.close()
    if shard is not None and shard[0] != 0:
        return 0  # the lead (process 0) reports the run
    from brdf_fit.io.stack import result_maps, write_maps

    full = res.result()
    arrays = result_maps(full)
    outs = Outputs(note=kept_note(args))
    outs.write("--out-dir", out / "maps", lambda: write_maps(out / "maps", arrays))
    return stream_report(
        args, entry, res, out, full, f"{values.shape[0]} problems", "maps/*.npy",
        {"problems": int(values.shape[0]), "maps": sorted(f"maps/{n}.npy" for n in arrays)},
        outs)


def run_images(args, entry, fix, init, fit_stream) -> int:
    """``fit-batch --images STACK.json --out-dir DIR``: one problem per texel of an image stack
    (:mod:`brdf_fit.io.stack`: M images, each one light and view direction). The pixels are
    written once into ``DIR/values.npy`` (image-major, memory-mapped; reused on ``--resume``),
    streamed block by block (non-finite pixels masked), and the maps written when every block
    is: ``DIR/maps/NAME.npy`` (H, W[, C]) and ``NAME.exr`` (OpenEXR, when installed) for
    ``params_*``, ``stderr_*``, ``undetermined_*``, ``converged``, ``residual_rms``."""

    from brdf_fit.data import DataError
    from brdf_fit.io.stack import read_stack, write_maps

    if args.data or args.values is not None:
        raise CLIError("give data files, --values or --images: one of them")
    if args.geometry is not None:
        raise CLIError("--images takes its directions from the stack description, not "
                       "--geometry")
    try:
        stack = read_stack(args.images)
    except (DataError, ImportError) as e:
        raise CLIError(str(e)) from None
    out = check_out_dir(args)
    check_new_run(args, out)
    shard, sync = join_run(args)
    lead = shard is None or shard[0] == 0
    vpath = out / "values.npy"
    if lead:
        out.mkdir(exist_ok=True)
        bar = BatchProgress(f"reading {stack.n_images} images of {stack.shape[1]}x"
                             f"{stack.shape[0]}", enabled=not args.quiet)
        try:
            values = stack.to_values(vpath, progress=lambda d, t: bar(d, t, "images"))
        except (DataError, ImportError) as e:
            raise CLIError(str(e)) from None
        finally:
            bar.close()
    if sync is not None and shard[1] > 1:
        from brdf_fit.fitting.distributed import DONE_TIMEOUT_S

        sync("brdf_fit.stack.values", timeout_s=DONE_TIMEOUT_S)  # the lead wrote them
    if not lead:
        values = np.moveaxis(np.load(vpath, mmap_mode="r"), 0, 1)

    def source(s, e):  # non-finite pixels (not measured) are masked, not fitted
        v = np.asarray(values[s:e], float)
        ok = np.isfinite(v)
        return {"values": np.where(ok, v, 0.0), "weight": ok.astype(float)}

    H, W = stack.shape
    bar = BatchProgress(f"{entry.name}, {H}x{W} texels of {stack.n_images} images",
                        enabled=not args.quiet)
    try:
        res = fit_stream(source, entry.name, out, n_problems=stack.n_texels, wi=stack.wi,
                         wo=stack.wo, meta=stack.fingerprint(), progress=bar,
                         **stream_kw(args, fix, init, shard, sync))
    finally:
        bar.close()
    if not lead:
        return 0  # the lead (process 0) reports the run
    full = res.result()
    # a texel without one finite pixel (outside the sample, not measured) has no fit: its
    # parameters and errors are NaN, its converged flag False, and it does not count against
    # the exit status (n_samples says how many pixels each texel's fit used)
    empty = np.asarray(full.n_samples) == 0
    maps = stack.to_maps(full)
    for name, a in maps.items():
        if name.startswith(("params_", "stderr_")):
            maps[name] = np.where(empty.reshape(H, W, *[1] * (a.ndim - 2)), np.nan, a)
        elif name.startswith("undetermined_"):
            maps[name] = a | empty.reshape(H, W, *[1] * (a.ndim - 2))
    maps["converged"] = maps["converged"] & ~empty.reshape(H, W)
    maps["n_samples"] = np.asarray(full.n_samples).reshape(H, W)
    try:
        import OpenEXR  # noqa: F401

        exr = True
    except ImportError:
        exr = False
    attributes = {"brdf_fit": json.dumps({"model": entry.name, "stack": str(stack.path),
                                          "metric": args.metric})}
    outs = Outputs(note=kept_note(args))
    outs.write("--out-dir", out / "maps",
               lambda: write_maps(out / "maps", maps, exr=exr, attributes=attributes))
    written = [pathlib.Path(p) for p in outs.written]
    if not exr and not args.json:
        print("OpenEXR is not installed: maps written as .npy only (pip install OpenEXR)",
              file=sys.stderr)
    what = f"{H}x{W} texels" + (f" ({int(empty.sum())} without a finite pixel: not fitted, "
                                  "NaN in the maps)" if empty.any() else "")
    return stream_report(
        args, entry, res, out, full, what, "values.npy, maps/*.npy"
        + (", maps/*.exr" if exr else ""),
        {"problems": stack.n_texels, "shape": [H, W], "images": stack.n_images,
         "unmeasured": int(empty.sum()),
         "maps": sorted(str(p.relative_to(out)) for p in written)}, outs, measured=~empty)
