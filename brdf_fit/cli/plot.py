"""``brdf-fit plot``: pictures of models, or of data against models."""

from __future__ import annotations

from brdf_fit.cli._common import (
    CLIError,
    Outputs,
    check_angles,
    check_output_file,
    fmt,
    load_registry,
    parse_params,
    read_data,
    short_params,
    use_x64,
)


def run(args) -> int:
    """Pictures of models (polar in-plane lobes + the hemisphere of the first model) or of data
    against models (in-plane slices + residuals), as PNG/PDF/SVG files."""
    import pathlib

    if not args.models and args.data is None:
        raise CLIError("plot needs a MODEL (e.g. 'brdf-fit plot ggx -o lobes.png') or --data FILE")
    if args.param and len(args.models) != 1:
        raise CLIError("--param needs exactly one MODEL")
    if args.fit and args.data is None:
        raise CLIError("--fit needs --data FILE")
    check_angles("--theta-i-deg", args.theta_i_deg)
    if any(t >= 90.0 for t in args.theta_i_deg):
        raise CLIError("--theta-i-deg: incidence angles must be below 90 (the horizon)")
    check_output_file(args.output, (".png", ".pdf", ".svg"), "-o")
    out = pathlib.Path(args.output)
    second = out.with_name(f"{out.stem}_{'residuals' if args.data else 'hemisphere'}{out.suffix}")
    reg = load_registry()
    entries = [reg.get(m) for m in args.models]  # unknown names fail before any work
    params = parse_params(args.param, entries[0]) if args.param else {}
    data = read_data(args.data) if args.data is not None else None
    if data is not None and not entries:
        raise CLIError("--data: name the MODEL(s) to draw against the data")
    use_x64()
    from brdf_fit import plot

    models = []
    for e in entries:
        if args.fit:
            from brdf_fit.fitting.single import fit

            r = fit(data, e.name, fix=params or None)
            models.append((f"{e.name} (fit, rms {r.residual_rms:.3g})", r.model))
            print(f"{e.name}: fitted {', '.join(f'{k}={fmt(v)}' for k, v in r.params.items())}"
                  f"{'' if r.converged else ' (NOT converged)'}")
        else:
            label = e.name + (f" ({short_params(params)})" if params else "")
            models.append((label, e.build(**params)))
    if data is None:
        fig1 = plot.model_lobes(models, args.theta_i_deg, channel=args.channel)
        fig2 = plot.hemisphere(models[0][1], args.theta_i_deg, channel=args.channel,
                               title=models[0][0])
    else:
        fig1 = plot.in_plane_slices(data, models, args.theta_i_deg, channel=args.channel,
                                    title=args.data)
        fig2 = plot.residuals(data, models, title=args.data)
    fig3 = None
    if data is not None and data.metadata.get("format") in ("merl", "rgl"):  # its own slice
        from brdf_fit.render import dense_data

        fig3 = plot.rusinkiewicz_slice(dense_data(args.data), models,
                                       channel=1 if args.channel is None else args.channel,
                                       title=args.data)
    outs = Outputs(note="the fitted parameters are printed above" if args.fit else None)
    outs.figure("-o", out, fig1)
    outs.figure("-o", second, fig2)
    if fig3 is not None:
        outs.figure("-o", out.with_name(f"{out.stem}_slice{out.suffix}"), fig3)
    for path in outs.written:
        print(f"wrote {path}")
    return outs.status()


def add_parser(sub) -> None:
    pl = sub.add_parser("plot", help="draw models (polar lobes, hemisphere) or data against "
                                     "models (in-plane slices, residuals)")
    pl.add_argument("models", nargs="*", metavar="MODEL", help="registry model name(s)")
    pl.add_argument("-o", "--output", required=True,
                    help="picture (.png, .pdf, .svg); a second one is written beside it "
                         "(NAME_hemisphere or NAME_residuals), and for MERL data a third, "
                         "NAME_slice: the phi_d = 90 deg slice of data, models and their log "
                         "ratio")
    pl.add_argument("--param", action="append", metavar="NAME=VALUE",
                    help="a parameter of the (single) MODEL; repeatable")
    pl.add_argument("--data", default=None, metavar="FILE",
                    help="measured data (.csv, .npz, .binary) to draw against the models")
    pl.add_argument("--fit", action="store_true", help="fit each MODEL to --data first")
    pl.add_argument("--theta-i-deg", type=float, nargs="+", default=[0.0, 30.0, 60.0],
                    metavar="DEG", help="incidence angles, one panel each (default 0 30 60)")
    pl.add_argument("--channel", type=int, default=None,
                    help="channel index to draw (default: G of RGB, else the first)")
    pl.set_defaults(func=run)
