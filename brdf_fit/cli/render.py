"""``brdf-fit render``: a sphere (or a plane seen at a grazing angle) shaded with a model, a
fit's result or dense MERL or RGL data under a directional light or an environment
(:mod:`brdf_fit.render`), as sRGB PNG or linear OpenEXR; data beside a model also gives NVIDIA's
FLIP between them."""

from __future__ import annotations

import json
import pathlib
import sys
import time

import numpy as np

from brdf_fit.cli._common import (
    CLIError,
    Outputs,
    check_output_file,
    fmt,
    load_registry,
    parse_params,
    positive_int,
    strict_json,
    use_x64,
)

#: the largest image side the command renders (4096^2 pixels: ~0.4 GB of float64 geometry)
MAX_SIZE = 4096
#: ``--scene plane``: the camera's default angle from the plane's normal (a grazing view)
VIEW_ZENITH_DEG = 80.0


def _from_fit(path: str, reg):
    """``(entry, params)`` of a ``brdf-fit fit --json`` answer."""
    try:
        with open(path, encoding="utf-8") as fh:
            doc = json.load(fh)
    except OSError as e:
        raise CLIError(f"{path}: cannot read ({e.strerror or e})") from None
    except json.JSONDecodeError as e:
        raise CLIError(f"{path}: not JSON ({e.msg}, line {e.lineno})") from None
    if not isinstance(doc, dict) or "model" not in doc or not isinstance(doc.get("params"), dict):
        raise CLIError(f"{path}: not a fit's JSON (brdf-fit fit --json): no 'model' and "
                       "'params'")
    entry = reg.get(doc["model"])
    params = {}
    for k, v in doc["params"].items():
        entry.param(k)  # an unknown name raises with the valid list
        params[k] = np.asarray(v, float) if isinstance(v, list) else float(v)
    return entry, params


def _irradiance(text: str | None, flag: str = "--irradiance") -> list[float] | None:
    """``--irradiance`` (or ``--environment``): non-negative finite numbers, comma-separated."""
    if text is None:
        return None
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise CLIError(f"{flag}: {text!r} is not a number or comma-separated numbers") from None
    if not all(0.0 <= v < float("inf") for v in values):
        raise CLIError(f"{flag}: {text!r}: every value must be finite and >= 0")
    return values


def _relative_stderr(image) -> float:
    """The median over the sphere's pixels and channels of standard error / estimate."""
    on = image.mask
    est, se = image.radiance[on], image.stderr[on]
    ok = est > 0
    return float(np.median(se[ok] / est[ok])) if ok.any() else 0.0


def run(args) -> int:
    check_output_file(args.output, (".png", ".exr"), "-o")
    if args.size > MAX_SIZE:
        raise CLIError(f"--size {args.size}: at most {MAX_SIZE}")
    plane = args.scene == "plane"
    if not 0.0 < args.view_zenith_deg < 90.0:
        raise CLIError(f"--view-zenith-deg {args.view_zenith_deg}: must be in (0, 90)")
    if args.view_zenith_deg != VIEW_ZENITH_DEG and not plane:
        raise CLIError("--view-zenith-deg sets the plane's view: with --scene plane")
    if args.light_zenith_deg is None:  # the plane's default puts the mirror glint at its centre
        args.light_zenith_deg = args.view_zenith_deg if plane else 45.0
    if args.light_azimuth_deg is None:
        args.light_azimuth_deg = 90.0 if plane else 0.0
    if not 0.0 <= args.light_zenith_deg < 90.0:
        raise CLIError(f"--light-zenith-deg {args.light_zenith_deg}: must be in [0, 90)")
    if plane and (args.environment is not None or args.environment_map is not None):
        raise CLIError("--environment lights the sphere: the plane renders under the "
                       "directional light")
    reg = load_registry()
    if args.fit is not None:
        if args.model is not None or args.param:
            raise CLIError("--fit gives the model and its parameters: no MODEL or --param")
        entry, params = _from_fit(args.fit, reg)
    elif args.model is None and args.data is None:
        raise CLIError("render needs a MODEL (e.g. 'brdf-fit render ggx -o sphere.png'), "
                       "--fit FIT.json or --data FILE.binary")
    elif args.model is None:
        if args.param:
            raise CLIError("--param needs a MODEL")
        entry, params = None, {}
    else:
        entry = reg.get(args.model)
        params = parse_params(args.param, entry)
    table = None
    if args.data is not None:
        from brdf_fit.data import DataError
        from brdf_fit.render import dense_data

        try:
            table = dense_data(args.data)
        except (DataError, OSError) as e:
            raise CLIError(str(e)) from None
        if table is None:
            raise CLIError(f"{args.data}: --data renders dense data only, a MERL .binary or an "
                           "RGL .bsdf file (sparse data cannot be rendered from themselves: "
                           "render a fit of them)")
    irradiance = _irradiance(args.irradiance)
    use_x64()
    from brdf_fit import render

    light = (args.size, args.light_zenith_deg, args.light_azimuth_deg,
             render.IRRADIANCE if irradiance is None else irradiance)
    model = None if entry is None else entry.build(**params)
    channels = 3 if model is None else max(3, model.channels() or 1)
    if irradiance is not None and len(irradiance) not in (1, channels):
        raise CLIError(f"--irradiance: one value or {channels} (one per channel), got "
                       f"{len(irradiance)}")
    environment = _irradiance(args.environment, "--environment")
    envmap = None
    if args.environment_map is not None:
        from brdf_fit.envmap import read_latlong

        try:
            envmap = read_latlong(args.environment_map)
        except (ValueError, ImportError) as e:
            raise CLIError(f"--environment-map: {e}") from None
        if envmap.texels.shape[-1] not in (1, channels):
            raise CLIError(f"--environment-map {args.environment_map}: "
                           f"{envmap.texels.shape[-1]} channels, the model has {channels}")
        if environment is None:
            environment = [1.0]  # the map as it is
    if environment is not None:
        if model is None or table is not None:
            raise CLIError("--environment renders a MODEL or --fit (dense data have no "
                           "sampler: they render under the directional light)")
        if len(environment) not in (1, channels):
            raise CLIError(f"--environment: one value or {channels} (one per channel), got "
                           f"{len(environment)}")
        if getattr(model, "is_delta", False):
            raise CLIError(f"--environment: {entry.name} has a delta lobe (no density for a "
                           "sampled estimate)")

    def draw(shaded):
        if plane:
            return render.render_plane(shaded, args.size, args.view_zenith_deg,
                                       light_zenith_deg=args.light_zenith_deg,
                                       light_azimuth_deg=args.light_azimuth_deg,
                                       irradiance=light[3])
        return render.render_sphere(shaded, *light)

    t0 = time.perf_counter()
    if environment is not None:
        from brdf_fit.cli._progress import progress_callback

        bar, progress = progress_callback(not args.quiet and args.size * args.size
                                          * args.spp > 1 << 20, "rendering the environment")
        try:
            image = render.render_sphere_environment(model, args.size, environment, args.spp,
                                                     args.seed, args.heuristic, progress,
                                                     environment=envmap)
        finally:
            bar.close()
    else:
        image = None if model is None else draw(model)
    measured = None if table is None else draw(table)
    flip = None
    if image is not None and measured is not None:
        try:
            flip = render.flip_error(measured, image)
        except ImportError as e:
            print(f"brdf-fit: warning: no FLIP difference: {e}", file=sys.stderr)
    seconds = time.perf_counter() - t0
    out = pathlib.Path(args.output)
    data_out = out if image is None else out.with_name(f"{out.stem}_data{out.suffix}")
    flip_out = out.with_name(f"{out.stem}_flip.png")
    outs = Outputs(note="nothing else was computed")
    if image is not None:
        outs.write("-o", out, lambda: [render.write_image(out, image, args.exposure)])
    if measured is not None:
        outs.write("-o", data_out, lambda: [render.write_image(data_out, measured,
                                                                 args.exposure)])
    if flip is not None:
        outs.write("-o", flip_out,
                   lambda: [render.write_png(flip_out, render.error_map_8bit(flip[0]))])
    shown = image if image is not None else measured
    on = shown.radiance[shown.mask]
    doc = {"model": None if entry is None else entry.name,
           "params": {k: np.asarray(v).tolist() for k, v in params.items()},
           "data": args.data, "out": str(out) if image is not None else None,
           "data_out": str(data_out) if measured is not None else None,
           "flip_out": str(flip_out) if flip is not None else None,
           "flip_mean": None if flip is None else flip[1],
           "size": args.size, "scene": args.scene,
           "view_zenith_deg": args.view_zenith_deg if plane else None,
           "environment": None if environment is None else {
               "radiance": image.irradiance.tolist(), "map": args.environment_map,
               "map_shape": None if envmap is None else list(envmap.shape),
               "samples_per_pixel": args.spp,
               "heuristic": args.heuristic, "seed": args.seed,
               "stderr_relative_median": _relative_stderr(image)},
           "light": None if environment is not None else {
               "zenith_deg": args.light_zenith_deg, "azimuth_deg": args.light_azimuth_deg,
               "irradiance": shown.irradiance.tolist()},
           "exposure_stops": args.exposure,
           "radiance_max": on.max(0).tolist() if on.size else None,
           "radiance_mean": on.mean(0).tolist() if on.size else None,
           "seconds": round(seconds, 4)}
    if args.json:
        print(strict_json(outs.annotate(doc)))
    else:
        what = ", ".join(f"{k}={fmt(v)}" for k, v in params.items())
        what = (args.data if entry is None else
                f"{entry.name}{f' ({what})' if what else ''}"
                + (f" beside {args.data}" if measured is not None else ""))
        lit = (f"the environment map {args.environment_map}" if envmap is not None else
               "a constant environment" if environment is not None else
               f"light at {args.light_zenith_deg:g} deg zenith, {args.light_azimuth_deg:g} deg "
               f"azimuth, irradiance {fmt(shown.irradiance)}")
        scene = (f"plane seen at {args.view_zenith_deg:g} deg from its normal" if plane
                 else "sphere")
        print(f"{what}: {scene} {args.size}x{args.size}, {lit}; largest radiance "
              f"{fmt(doc['radiance_max'] or 0.0)}; {seconds:.2f} s")
        if flip is not None:
            print(f"FLIP (data -> model), mean over the sphere: {flip[1]:.4g}")
        if environment is not None:
            kind = (f"environment map ({envmap.shape[0]} x {envmap.shape[1]}) times "
                    if envmap is not None else "constant environment of radiance ")
            print(f"{kind}{fmt(image.irradiance)}: {args.spp} "
                  f"samples per pixel, multiple importance sampling ({args.heuristic} "
                  f"heuristic); median relative standard error "
                  f"{doc['environment']['stderr_relative_median']:.3g}")
        for path in outs.written:
            print(f"wrote {path}")
    return outs.status()


def add_parser(sub) -> None:
    r = sub.add_parser("render", help="a sphere (or a plane at a grazing view) shaded with a "
                                      "model (or a fit's result) under a directional light, as "
                                      "PNG or OpenEXR")
    r.add_argument("model", nargs="?", default=None, metavar="MODEL",
                   help="registry model name (or --fit)")
    r.add_argument("-o", "--output", required=True,
                   help="image: .png (sRGB, 8 bits) or .exr (linear float32 RGB + A mask)")
    r.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="a parameter of MODEL (a number or one per channel); repeatable")
    r.add_argument("--fit", default=None, metavar="FIT.json",
                   help="the JSON answer of 'brdf-fit fit --json': its model and parameters")
    r.add_argument("--data", default=None, metavar="FILE",
                   help="dense data rendered from themselves, a MERL .binary (trilinear "
                        "between the bin centres) or an RGL .bsdf (Mitsuba's measured "
                        "plugin's interpolation), written as NAME_data beside -o; with a MODEL "
                        "or --fit also NAME_flip.png, NVIDIA's FLIP between the two (its mean "
                        "in the output)")
    r.add_argument("--environment", default=None, metavar="L",
                   help="light the sphere by a constant environment of radiance L (a number or "
                        "one per channel) instead of the directional light, estimated with "
                        "multiple importance sampling of the model's sampler and the "
                        "environment's; with --environment-map, the map's scale")
    r.add_argument("--environment-map", default=None, metavar="FILE.exr",
                   help="light the sphere by a latitude-longitude OpenEXR map (linear R, G, B; "
                        "+y up, Mitsuba 3's envmap convention), drawn from in proportion to "
                        "its radiance; 'sky' for the package's procedural sky with a sun")
    r.add_argument("--spp", type=positive_int, default=64, metavar="N",
                   help="--environment: samples per pixel, each one of both strategies "
                        "(default 64); the output gives the estimate's standard error")
    r.add_argument("--heuristic", choices=("balance", "power"), default="balance",
                   help="--environment: the MIS weights (Veach 1997: balance, or power with "
                        "beta = 2)")
    r.add_argument("--seed", type=int, default=0, help="--environment: the random seed")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.add_argument("--size", type=positive_int, default=256, metavar="N",
                   help="image side in pixels (default 256)")
    r.add_argument("--scene", choices=("sphere", "plane"), default="sphere",
                   help="a sphere seen along its axis (default), or a plane seen by a pinhole "
                        "camera at a grazing angle up to its horizon, where grazing behaviour "
                        "shows (Fresnel, off-specular peaks, masking); Mitsuba 3's 'rectangle' "
                        "under a 'perspective' sensor of 30 degrees")
    r.add_argument("--view-zenith-deg", type=float, default=VIEW_ZENITH_DEG, metavar="DEG",
                   help=f"--scene plane: the camera's angle from the plane's normal (default "
                        f"{VIEW_ZENITH_DEG:g})")
    r.add_argument("--light-zenith-deg", type=float, default=None, metavar="DEG",
                   help="the light's angle from the camera's axis (the sphere; default 45) or "
                        "from the plane's normal (default the view's zenith)")
    r.add_argument("--light-azimuth-deg", type=float, default=None, metavar="DEG",
                   help="the light's azimuth, from the image's right (+x) toward its top (the "
                        "sphere; default 0) or toward the far side (the plane; default 90: with "
                        "the default zenith the mirror glint at the centre)")
    r.add_argument("--irradiance", default=None, metavar="E",
                   help="the light's irradiance, a number or one per channel (default pi: a "
                        "white Lambertian surface facing the light renders 1)")
    r.add_argument("--exposure", type=float, default=0.0, metavar="STOPS",
                   help="PNG only: radiance times 2^STOPS before clipping to [0, 1] and the "
                        "sRGB encoding (default 0)")
    r.add_argument("--json", action="store_true", help="print a JSON summary")
    r.set_defaults(func=run)
