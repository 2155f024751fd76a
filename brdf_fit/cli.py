"""Command-line interface: thin wrappers that parse, call the library, print tables or JSON.

    brdf-fit models [--json]
    brdf-fit eval MODEL [--param NAME=VALUE ...] [--theta-i-deg ...] [--theta-o-deg ...] [--json]
    brdf-fit check MODEL [--param NAME=VALUE ...] [--check NAME ...] [--json]
    brdf-fit check --all [--json]
    brdf-fit demo [--json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np


class CLIError(Exception):
    """A user error: printed as one line, exit status 2."""


def _registry():
    from . import registry

    return registry


def parse_params(items: list[str] | None, entry) -> dict:
    """``NAME=VALUE`` pairs; VALUE is a number or comma-separated numbers (one per channel)."""
    out = {}
    for item in items or []:
        if "=" not in item:
            raise CLIError(f"--param expects NAME=VALUE, got {item!r}")
        name, _, text = item.partition("=")
        name = name.strip()
        entry.param(name)  # unknown names raise with the valid list
        try:
            vals = [float(v) for v in text.split(",")]
        except ValueError:
            raise CLIError(
                f"--param {name}: {text!r} is not a number or comma-separated numbers"
            ) from None
        out[name] = vals[0] if len(vals) == 1 else np.asarray(vals)
    return out


def _fmt(v) -> str:
    a = np.atleast_1d(np.asarray(v, dtype=float))
    return ",".join(f"{x:.4g}" for x in a) if a.size > 1 else f"{a[0]:.4g}"


def cmd_models(args) -> int:
    reg = _registry()
    entries = reg.entries()
    if args.json:
        print(json.dumps([e.to_dict() for e in entries], indent=2))
        return 0
    print(f"{len(entries)} models (brdf-fit eval MODEL --param NAME=VALUE):\n")
    width = max(len(e.name) for e in entries)
    for e in entries:
        alias = f"  (aliases: {', '.join(e.aliases)})" if e.aliases else ""
        print(f"{e.name:<{width}}  {e.description}{alias}")
        for p in e.params:
            ch = " [channels]" if p.channels else ""
            print(f"{'':<{width}}    {p.name} = {_fmt(p.default_value())}  in {p.interval()}{ch}"
                  f"  {p.doc}")
        print(f"{'':<{width}}    ref: {e.reference}")
    return 0


def _in_plane(theta_i_deg, theta_o_deg, phi_i_deg=0.0):
    """Direction pairs in the plane of incidence, specular geometry phi_o = phi_i + 180 deg."""
    ti, to = np.meshgrid(np.radians(theta_i_deg), np.radians(theta_o_deg), indexing="ij")
    pi_ = math.radians(phi_i_deg)
    po = pi_ + math.pi
    wi = np.stack([np.sin(ti) * np.cos(pi_), np.sin(ti) * np.sin(pi_), np.cos(ti)], -1)
    wo = np.stack([np.sin(to) * np.cos(po), np.sin(to) * np.sin(po), np.cos(to)], -1)
    return wi, wo


def _check_angles(name, values):
    for v in values:
        if not (0.0 <= v <= 90.0):
            raise CLIError(f"{name}: {v} deg is outside [0, 90] (below the horizon or negative)")


def evaluation_table(model_name: str, params: dict, theta_i_deg, theta_o_deg) -> dict:
    import jax.numpy as jnp

    entry = _registry().get(model_name)
    model = entry.build(**params)
    wi, wo = _in_plane(theta_i_deg, theta_o_deg)
    f = np.asarray(model.eval(jnp.asarray(wi), jnp.asarray(wo)))
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
    params = ", ".join(f"{k}={_fmt(v)}" for k, v in table["params"].items())
    print(f"{table['model']} ({params}); f_r in 1/sr, {table['geometry']}")
    print(f"{'theta_i':>8} {'theta_o':>8}  f_r")
    for r in table["rows"]:
        vals = "  ".join(f"{v:11.5g}" for v in r["brdf"])
        print(f"{r['theta_i_deg']:8.1f} {r['theta_o_deg']:8.1f}  {vals}")


def cmd_eval(args) -> int:
    entry = _registry().get(args.model)
    params = parse_params(args.param, entry)
    _check_angles("--theta-i-deg", args.theta_i_deg)
    _check_angles("--theta-o-deg", args.theta_o_deg)
    table = evaluation_table(entry.name, params, args.theta_i_deg, args.theta_o_deg)
    if args.json:
        print(json.dumps(table, indent=2))
    else:
        _print_eval(table)
    return 0


class _Progress:
    """One status line on stderr (rewritten in place on a terminal, plain lines otherwise)."""

    def __init__(self, total: int, enabled: bool = True):
        self.total, self.done, self.enabled = total, 0, enabled
        self.tty = sys.stderr.isatty()

    def __call__(self, model: str, check: str) -> None:
        if not self.enabled:
            return
        self.done += 1
        width = 24
        filled = int(width * (self.done - 1) / max(self.total, 1))
        bar = "#" * filled + "-" * (width - filled)
        msg = f"[{bar}] {self.done}/{self.total} {model}: {check}"
        if self.tty:
            print("\r" + msg.ljust(78), end="", file=sys.stderr, flush=True)
        else:
            print(msg, file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.enabled and self.tty:
            print("\r" + " " * 78 + "\r", end="", file=sys.stderr, flush=True)


def _print_check_table(results) -> None:
    print(f"{results[0].model}")
    print(f"  {'check':<20} {'statistic':>12} {'threshold':>12}  {'status':<26} {'time':>7}")
    for r in results:
        stat = "-" if not r.applicable else f"{r.statistic:12.4g}"
        thr = "-" if not r.applicable else f"{r.threshold:12.4g}"
        print(f"  {r.check:<20} {stat:>12} {thr:>12}  {r.status:<26} {r.seconds:6.2f}s")
        if r.expected_failure and r.applicable:
            print(f"  {'':<20} reason: {r.expected_failure}")
        elif not r.applicable:
            print(f"  {'':<20} ({r.details.get('reason', '')})")


def cmd_check(args) -> int:
    import jax

    if not args.float32:  # verification wants float64 (reference tolerances are set for it)
        jax.config.update("jax_enable_x64", True)
    from . import checks

    reg = _registry()
    if args.all and args.model:
        raise CLIError("give a MODEL or --all, not both")
    if not args.all and not args.model:
        raise CLIError("give a MODEL (see 'brdf-fit models') or --all")
    names = list(reg.names()) if args.all else [reg.get(args.model).name]
    params = {} if args.all else parse_params(args.param, reg.get(names[0]))
    if args.all and args.param:
        raise CLIError("--param applies to a single MODEL, not to --all")
    selected = args.check or list(checks.CHECKS)
    for c in selected:
        if c not in checks.CHECKS:
            raise CLIError(f"unknown check {c!r}; valid checks: {', '.join(checks.CHECKS)}")
    progress = _Progress(len(names) * len(selected), enabled=not args.quiet)
    all_results = []
    try:
        for name in names:
            res = checks.run_checks(name, params=params, checks=selected, progress=progress)
            all_results.append(res)
            if not args.json:
                progress.close()
                _print_check_table(res)
                print()
    finally:
        progress.close()
    flat = [r for res in all_results for r in res]
    bad = [r for r in flat if not r.ok]
    if args.json:
        print(json.dumps([r.to_dict() for r in flat], indent=2))
    else:
        n_exp = sum(1 for r in flat if r.applicable and r.expected_failure and not r.passed)
        print(f"{len(flat)} checks on {len(names)} model(s): {len(bad)} failed, "
              f"{n_exp} expected failure(s) (declared in the registry with reasons)")
    return 1 if bad else 0


def cmd_demo(args) -> int:
    """The main job on an embedded default. For now: the model list and evaluation tables; the
    fitting issue grows it into synthesise -> fit -> compare -> check -> plots."""
    angles = [0.0, 30.0, 60.0, 80.0, 89.0]
    tables = [
        evaluation_table("ggx-conductor", {"alpha": 0.2}, [30.0, 60.0], angles),
        evaluation_table("ggx-plastic", {}, [30.0, 60.0], angles),
        evaluation_table("lambert", {}, [30.0], [0.0, 45.0]),
    ]
    if args.json:
        print(json.dumps({"models": list(_registry().names()), "tables": tables}, indent=2))
        return 0
    cmd_models(argparse.Namespace(json=False))
    print()
    for t in tables:
        _print_eval(t)
        print()
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="brdf-fit", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="command", required=True)

    m = sub.add_parser("models", help="list the registered models and their parameters")
    m.add_argument("--json", action="store_true", help="machine-readable output")
    m.set_defaults(func=cmd_models)

    e = sub.add_parser("eval", help="evaluate a model in the plane of incidence")
    e.add_argument("model")
    e.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="parameter value (comma-separated for channels); repeatable")
    e.add_argument("--theta-i-deg", type=float, nargs="+", default=[0.0, 30.0, 60.0])
    e.add_argument("--theta-o-deg", type=float, nargs="+", default=[0.0, 30.0, 60.0, 85.0])
    e.add_argument("--json", action="store_true")
    e.set_defaults(func=cmd_eval)

    c = sub.add_parser("check", help="energy, reciprocity, normalisation and sampling checks")
    c.add_argument("model", nargs="?", help="registry name (see 'brdf-fit models')")
    c.add_argument("--all", action="store_true", help="check every registered model")
    c.add_argument("--param", action="append", metavar="NAME=VALUE")
    c.add_argument("--check", action="append", metavar="NAME",
                   help="run only this check (repeatable); default: all")
    c.add_argument("--json", action="store_true",
                   help="one record per (model, check): model, check, passed, statistic, ...")
    c.add_argument("--quiet", action="store_true", help="no progress bar")
    c.add_argument("--float32", action="store_true",
                   help="check in float32 (default: float64; tolerances scale with epsilon)")
    c.set_defaults(func=cmd_check)

    d = sub.add_parser("demo", help="the main job on an embedded default (no input needed)")
    d.add_argument("--json", action="store_true")
    d.set_defaults(func=cmd_demo)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from ._validate import ParameterError

    try:
        return int(args.func(args) or 0)
    except (CLIError, ParameterError) as exc:
        print(f"brdf-fit: error: {exc}", file=sys.stderr)
        return 2
    except KeyError as exc:  # unknown model (registry.UnknownModelError)
        print(f"brdf-fit: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into `head` and closed early: not an error
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
