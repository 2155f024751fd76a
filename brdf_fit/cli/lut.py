"""``brdf-fit lut``: lookup tables (dfg, albedo, eavg) written to files."""

from __future__ import annotations

from brdf_fit.cli._common import (
    CLIError,
    Outputs,
    check_output_file,
    load_registry,
    parse_params,
    positive_int,
    strict_json,
)
from brdf_fit.cli._progress import progress_callback

LUT_TABLES = ("dfg", "albedo", "eavg")


#: memory a node of an albedo table takes at its peak (see _lut_albedo)
LUT_BYTES_PER_NODE = 128


def _lut_albedo(args) -> int:
    """``lut albedo MODEL --axis mu=64 --axis alpha=64`` and ``lut eavg MODEL --axis ...``."""
    import time

    if args.model is None:
        raise CLIError(f"lut {args.table} needs a MODEL (see 'brdf-fit models')")
    for flag, bad in (("--masking", args.masking), ("--channels", args.channels)):
        if bad is not None:
            raise CLIError(f"{flag} is a lut dfg option")
    if args.layout not in ("default", "endpoints"):
        raise CLIError(f"lut {args.table}: --layout is default (texel centres) or endpoints")
    from brdf_fit.tables.albedo import parse_axis

    axes = {}
    for text in args.axis or []:
        try:
            name, spec = parse_axis(text)
        except ValueError as e:
            raise CLIError(str(e)) from None
        if name in axes:
            raise CLIError(f"--axis {name} given twice")
        axes[name] = spec
    if args.table == "albedo" and "mu" not in axes:
        raise CLIError("lut albedo needs --axis mu=N (and usually a parameter axis, e.g. "
                       "--axis alpha=64)")
    if args.table == "eavg" and ("mu" in axes or not axes):
        raise CLIError("lut eavg averages over mu: give parameter axes only, e.g. --axis alpha=64")
    if len(axes) > 3:
        raise CLIError(f"at most 3 axes, got {len(axes)}")
    entry = load_registry().get(args.model)
    params = parse_params(args.param, entry)
    for name in axes:
        if name != "mu":
            entry.param(name)  # unknown names raise with the valid list
    from brdf_fit.tables.export import check_output

    try:
        check_output(args.output, half=args.half, n_axes=len(axes))
    except (ValueError, ImportError) as e:
        raise CLIError(str(e)) from None
    if args.plot is not None:
        check_output_file(args.plot, (".png", ".pdf", ".svg"), "--plot")
        if len(axes) != 2:
            raise CLIError("--plot draws 2-D tables")
    from brdf_fit.tables.albedo import albedo_table, average_table

    centres = args.layout == "default"
    total = 1
    for spec in axes.values():
        total *= spec if isinstance(spec, int) else spec[0]
    from brdf_fit.core.limits import check_bytes

    # the table's values (float64, up to 4 channels), their float32 and file copies; the
    # quadrature itself is streamed in blocks (tables/_stream.py) and does not grow with it
    check_bytes(total * LUT_BYTES_PER_NODE,
                f"lut {args.table}: {total:,} nodes at {LUT_BYTES_PER_NODE} bytes each")
    label = (f"{args.table} {args.model} ({total} nodes"
             + (", then E_avg" if args.table == "albedo" else "") + ")")
    bar, progress = progress_callback(not args.quiet, label)
    t0 = time.perf_counter()
    try:
        if args.table == "albedo":
            table = albedo_table(entry.name, axes, params, centres=centres, progress=progress)
        else:
            table = average_table(entry.name, axes, params, centres=centres, progress=progress)
    except ValueError as e:
        raise CLIError(str(e)) from None
    finally:
        bar.close()
    seconds = time.perf_counter() - t0
    outs = _write(args, table, f"{args.table} {entry.name}")
    paths = outs.written
    meta = table.meta
    doc = {"table": args.table, "model": entry.name, "params": meta["params"],
           "axes": [a.to_dict() for a in table.axes], "channels": list(table.channels),
           "error_estimate": meta.get("error_estimate"), "seconds": round(seconds, 3),
           "files": paths}
    if args.json:
        print(strict_json(outs.annotate(doc)))
    else:
        err = (meta.get("error_estimate") or {}).get("max_abs")
        shape = " x ".join(f"{a.name}={a.n}" for a in table.axes)
        est = ("no error estimate is computed for this table" if err is None
               else f"error estimate {err:.2g} max abs")
        print(f"{args.table} of {entry.name} on {shape} ({','.join(table.channels)}): "
              f"{est}; {seconds:.2f} s")
        for p in paths:
            print(f"wrote {p}")
    return outs.status()


def _write(args, table, title: str):
    """The table to ``-o`` (kept in a temporary folder if that fails: it may have taken long)
    and its picture to ``--plot``; returns the :class:`Outputs`."""
    from brdf_fit.tables.export import write_table

    outs = Outputs(note="the table's description is printed instead")
    outs.write("-o", args.output, lambda: write_table(table, args.output, half=args.half),
               elsewhere=lambda other: write_table(table, other, half=args.half))
    if args.plot is not None:
        from brdf_fit.plot import table_maps

        outs.figure("--plot", args.plot, table_maps(table, title=title))
    return outs


def run(args) -> int:
    """Generate a lookup table (:mod:`brdf_fit.tables`) and write it; every option and the
    output path are checked before any work."""
    import time

    from brdf_fit.tables.layouts import CHANNEL_SETS, LAYOUTS

    if args.table not in LUT_TABLES:
        raise CLIError(f"unknown table {args.table!r}; valid tables: {', '.join(LUT_TABLES)}")
    if args.table != "dfg":
        return _lut_albedo(args)
    if args.model is not None or args.axis or args.param:
        raise CLIError("lut dfg takes no MODEL, --axis or --param (it is GGX's A, B over mu and "
                       "roughness; see lut albedo)")
    if args.layout not in LAYOUTS:
        raise CLIError(f"unknown layout {args.layout!r}; valid layouts: {', '.join(LAYOUTS)}")
    masks = ("height-correlated", "separable", "karis")
    if args.masking is not None and args.masking not in masks:
        raise CLIError(f"unknown masking {args.masking!r}; valid: {', '.join(masks)}")
    if args.size < 2 or args.size > 4096:
        raise CLIError(f"--size must be in [2, 4096], got {args.size}")
    channels = None
    if args.channels is not None:
        channels = tuple(c.strip() for c in args.channels.split(","))
        if channels not in CHANNEL_SETS:
            raise CLIError(f"--channels {args.channels!r}: choose one of "
                           f"{', '.join(','.join(c) for c in CHANNEL_SETS)}")
    from brdf_fit.tables.export import check_output

    try:
        check_output(args.output, half=args.half)
    except (ValueError, ImportError) as e:
        raise CLIError(str(e)) from None
    if args.plot is not None:
        check_output_file(args.plot, (".png", ".pdf", ".svg"), "--plot")
    import dataclasses

    from brdf_fit.tables.dfg import dfg_table
    from brdf_fit.tables.layouts import resolve_layout

    layout = resolve_layout(args.layout)
    if channels is not None:
        layout = dataclasses.replace(layout, channels=channels)
    bar, progress = progress_callback(not args.quiet, f"dfg {args.size}x{args.size} texels")
    t0 = time.perf_counter()
    table = dfg_table(args.size, args.masking, layout=layout, progress=progress)
    bar.close()
    seconds = time.perf_counter() - t0
    outs = _write(args, table, f"DFG {args.size}x{args.size}, {table.meta['masking']}")
    paths = outs.written
    meta = table.meta
    doc = {"table": "dfg", "size": args.size, "layout": meta["layout"],
           "masking": meta["masking"], "channels": list(table.channels),
           "quadrature": meta["quadrature"],
           "error_estimate": {k: v for k, v in meta.get("error_estimate", {}).items()
                              if k in ("max_abs", "method")},
           "seconds": round(seconds, 3), "files": paths}
    if args.json:
        print(strict_json(outs.annotate(doc)))
    else:
        err = doc["error_estimate"].get("max_abs")
        print(f"DFG {args.size}x{args.size} ({meta['masking']} masking, layout {args.layout}, "
              f"channels {','.join(table.channels)}): error estimate "
              f"{'-' if err is None else f'{err:.2g}'} max abs; {seconds:.2f} s")
        for p in paths:
            print(f"wrote {p}")
    return outs.status()


def add_parser(sub) -> None:
    t = sub.add_parser("lut", help="generate a lookup table (dfg: split-sum A, B of GGX; albedo "
                                   "E(mu, ...) or eavg E_avg(...) of any model) as .npz, .exr, "
                                   ".png (16 bit) or .h")
    t.add_argument("table", help="dfg, albedo or eavg")
    t.add_argument("model", nargs="?", default=None, help="albedo/eavg: registry model name")
    t.add_argument("--axis", action="append", metavar="NAME=N[:LO:HI]",
                   help="albedo/eavg: a grid axis, mu or a model parameter (over its declared "
                        "interval unless LO:HI are given); repeatable, in table order")
    t.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="albedo/eavg: a fixed model parameter (default: the registry's)")
    t.add_argument("-o", "--output", required=True,
                   help="output file; the format from the extension: .npz (+ .json sidecar), "
                        ".exr, .png, .h")
    t.add_argument("--size", type=positive_int, default=128, metavar="N",
                   help="N x N texels (default 128)")
    t.add_argument("--masking", default=None,
                   help="height-correlated (default), separable or karis (k = alpha/2, UE4)")
    t.add_argument("--layout", default="default",
                   help="dfg: default, khronos, filament, ue4, cycles (texel grid, roughness "
                        "axis, image row order and channels of that engine's table); "
                        "albedo/eavg: default (texel centres) or endpoints")
    t.add_argument("--channels", default=None, metavar="A,B|B,E|E",
                   help="what to store (default: the layout's); E = A + B")
    t.add_argument("--half", action="store_true", help=".exr: half floats instead of float32")
    t.add_argument("--plot", default=None, metavar="PNG", help="also draw the table and its "
                                                              "error estimate")
    t.add_argument("--json", action="store_true", help="print the table's metadata as JSON")
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    t.set_defaults(func=run)
