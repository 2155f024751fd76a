"""``brdf-fit render``: a sphere shaded with a model, or with a fit's result, under a
directional light (:mod:`brdf_fit.render`), as sRGB PNG or linear OpenEXR."""

from __future__ import annotations

import json
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
    use_x64,
)

#: the largest image side the command renders (4096^2 pixels: ~0.4 GB of float64 geometry)
MAX_SIZE = 4096


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


def run(args) -> int:
    check_output_file(args.output, (".png", ".exr"), "-o")
    if args.size > MAX_SIZE:
        raise CLIError(f"--size {args.size}: at most {MAX_SIZE}")
    if not 0.0 <= args.light_zenith_deg < 90.0:
        raise CLIError(f"--light-zenith-deg {args.light_zenith_deg}: must be in [0, 90)")
    reg = load_registry()
    if args.fit is not None:
        if args.model is not None or args.param:
            raise CLIError("--fit gives the model and its parameters: no MODEL or --param")
        entry, params = _from_fit(args.fit, reg)
    elif args.model is None:
        raise CLIError("render needs a MODEL (e.g. 'brdf-fit render ggx -o sphere.png') or "
                       "--fit FIT.json")
    else:
        entry = reg.get(args.model)
        params = parse_params(args.param, entry)
    irradiance = [float(v) for v in args.irradiance.split(",")] if args.irradiance else None
    use_x64()
    from brdf_fit import render

    t0 = time.perf_counter()
    model = entry.build(**params)
    image = render.render_sphere(model, args.size, args.light_zenith_deg, args.light_azimuth_deg,
                                 render.IRRADIANCE if irradiance is None else irradiance)
    seconds = time.perf_counter() - t0
    outs = Outputs(note="nothing else was computed")
    outs.write("-o", args.output, lambda: [render.write_image(args.output, image,
                                                              args.exposure)])
    on = image.radiance[image.mask]
    doc = {"model": entry.name, "params": {k: np.asarray(v).tolist() for k, v in params.items()},
           "out": args.output, "size": args.size,
           "light": {"zenith_deg": args.light_zenith_deg,
                     "azimuth_deg": args.light_azimuth_deg,
                     "irradiance": image.irradiance.tolist()},
           "exposure_stops": args.exposure,
           "radiance_max": on.max(0).tolist() if on.size else None,
           "radiance_mean": on.mean(0).tolist() if on.size else None,
           "seconds": round(seconds, 4)}
    if args.json:
        print(json.dumps(outs.annotate(doc), indent=2))
    else:
        shown = ", ".join(f"{k}={fmt(v)}" for k, v in params.items())
        print(f"{entry.name}{f' ({shown})' if shown else ''}: sphere {args.size}x{args.size}, "
              f"light at {args.light_zenith_deg:g} deg zenith, {args.light_azimuth_deg:g} deg "
              f"azimuth, irradiance {fmt(image.irradiance)}; largest radiance "
              f"{fmt(doc['radiance_max'] or 0.0)}; {seconds:.2f} s")
        for path in outs.written:
            print(f"wrote {path}")
    return outs.status()


def add_parser(sub) -> None:
    r = sub.add_parser("render", help="a sphere shaded with a model (or a fit's result) under a "
                                      "directional light, as PNG or OpenEXR")
    r.add_argument("model", nargs="?", default=None, metavar="MODEL",
                   help="registry model name (or --fit)")
    r.add_argument("-o", "--output", required=True,
                   help="image: .png (sRGB, 8 bits) or .exr (linear float32 RGB + A mask)")
    r.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="a parameter of MODEL (a number or one per channel); repeatable")
    r.add_argument("--fit", default=None, metavar="FIT.json",
                   help="the JSON answer of 'brdf-fit fit --json': its model and parameters")
    r.add_argument("--size", type=positive_int, default=256, metavar="N",
                   help="image side in pixels (default 256)")
    r.add_argument("--light-zenith-deg", type=float, default=45.0, metavar="DEG",
                   help="the light's angle from the camera's axis (default 45)")
    r.add_argument("--light-azimuth-deg", type=float, default=0.0, metavar="DEG",
                   help="the light's azimuth, from the image's right (+x) toward its top "
                        "(default 0)")
    r.add_argument("--irradiance", default=None, metavar="E",
                   help="the light's irradiance, a number or one per channel (default pi: a "
                        "white Lambertian surface facing the light renders 1)")
    r.add_argument("--exposure", type=float, default=0.0, metavar="STOPS",
                   help="PNG only: radiance times 2^STOPS before clipping to [0, 1] and the "
                        "sRGB encoding (default 0)")
    r.add_argument("--json", action="store_true", help="print a JSON summary")
    r.set_defaults(func=run)
