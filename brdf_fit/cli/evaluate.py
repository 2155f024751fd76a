"""``brdf-fit eval``: a model evaluated in the plane of incidence."""

from __future__ import annotations

import math

import numpy as np

from brdf_fit.cli._common import (
    check_angles,
    fmt,
    load_registry,
    parse_params,
    strict_json,
)


def _in_plane(theta_i_deg, theta_o_deg, phi_i_deg=0.0):
    """Direction pairs in the plane of incidence, specular geometry phi_o = phi_i + 180 deg."""
    ti, to = np.meshgrid(np.radians(theta_i_deg), np.radians(theta_o_deg), indexing="ij")
    pi_ = math.radians(phi_i_deg)
    po = pi_ + math.pi
    wi = np.stack([np.sin(ti) * np.cos(pi_), np.sin(ti) * np.sin(pi_), np.cos(ti)], -1)
    wo = np.stack([np.sin(to) * np.cos(po), np.sin(to) * np.sin(po), np.cos(to)], -1)
    return wi, wo


def evaluation_table(model_name: str, params: dict, theta_i_deg, theta_o_deg) -> dict:
    import jax.numpy as jnp

    from brdf_fit.models._base import evaluate

    entry = load_registry().get(model_name)
    model = entry.build(**params)
    wi, wo = _in_plane(theta_i_deg, theta_o_deg)
    # one compiled program (model.eval called eagerly compiled 32, one per operation of ggx)
    f = np.asarray(evaluate(model, jnp.asarray(wi), jnp.asarray(wo)))
    rows = []
    for a, ti in enumerate(theta_i_deg):
        for b, to in enumerate(theta_o_deg):
            rows.append({"theta_i_deg": float(ti), "theta_o_deg": float(to),
                         "brdf": np.atleast_1d(f[a, b]).tolist()})
    used = {k: np.asarray(v).tolist() for k, v in entry.defaults().items()}
    used.update({k: np.asarray(v).tolist() for k, v in params.items()})
    return {"model": entry.name, "params": used, "geometry": "in-plane, phi_o = phi_i + 180 deg",
            "unit": "1/sr", "rows": rows}


def _print_eval(table: dict) -> None:
    params = ", ".join(f"{k}={fmt(v)}" for k, v in table["params"].items())
    print(f"{table['model']} ({params}); f_r in 1/sr, {table['geometry']}")
    print(f"{'theta_i':>8} {'theta_o':>8}  f_r")
    for r in table["rows"]:
        vals = "  ".join(f"{v:11.5g}" for v in r["brdf"])
        print(f"{r['theta_i_deg']:8.1f} {r['theta_o_deg']:8.1f}  {vals}")


def run(args) -> int:
    entry = load_registry().get(args.model)
    params = parse_params(args.param, entry)
    check_angles("--theta-i-deg", args.theta_i_deg)
    check_angles("--theta-o-deg", args.theta_o_deg)
    table = evaluation_table(entry.name, params, args.theta_i_deg, args.theta_o_deg)
    if args.json:
        print(strict_json(table))
    else:
        _print_eval(table)
    return 0


def add_parser(sub) -> None:
    e = sub.add_parser("eval", help="evaluate a model in the plane of incidence")
    e.add_argument("model")
    e.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="parameter value (comma-separated for channels); repeatable")
    e.add_argument("--theta-i-deg", type=float, nargs="+", default=[0.0, 30.0, 60.0],
                   metavar="DEG", help="zenith angles of the light in [0, 90] degrees "
                                       "(default: 0 30 60)")
    e.add_argument("--theta-o-deg", type=float, nargs="+", default=[0.0, 30.0, 60.0, 85.0],
                   metavar="DEG", help="zenith angles of the viewer in [0, 90] degrees, on the "
                                       "far side of the normal (default: 0 30 60 85)")
    e.add_argument("--json", action="store_true", help="machine-readable table")
    e.set_defaults(func=run)
