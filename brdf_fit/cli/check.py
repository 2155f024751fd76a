"""``brdf-fit check``: energy, reciprocity, normalisation and sampling checks of models."""

from __future__ import annotations

from brdf_fit.cli._common import (
    CLIError,
    load_registry,
    parse_params,
    strict_json,
)
from brdf_fit.cli._progress import Progress

#: the check names, for --help without importing JAX (tests/cli holds them equal to
#: brdf_fit.verify.checks.CHECKS)
CHECK_NAMES = ("non-negative", "reciprocity", "energy", "ndf-normalisation", "weak-white-furnace",
               "white-furnace", "pdf-normalisation", "sampling-weight", "chi2", "finite")


def print_check_table(results) -> None:
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


def run(args) -> int:
    import jax

    if not args.float32:  # verification wants float64 (reference tolerances are set for it)
        jax.config.update("jax_enable_x64", True)
    from brdf_fit.verify import checks

    reg = load_registry()
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
    progress = Progress(len(names) * len(selected), enabled=not args.quiet)
    all_results = []
    try:
        for name in names:
            res = checks.run_checks(name, params=params, checks=selected, progress=progress)
            all_results.append(res)
            if not args.json:
                progress.close()
                print_check_table(res)
                print()
    finally:
        progress.close()
    flat = [r for res in all_results for r in res]
    bad = [r for r in flat if not r.ok]
    if args.json:
        print(strict_json([r.to_dict() for r in flat]))
    else:
        n_exp = sum(1 for r in flat if r.applicable and r.expected_failure and not r.passed)
        print(f"{len(flat)} checks on {len(names)} model(s): {len(bad)} failed, "
              f"{n_exp} expected failure(s) (declared in the registry with reasons)")
    return 1 if bad else 0


def add_parser(sub) -> None:
    c = sub.add_parser("check", help="energy, reciprocity, normalisation and sampling checks")
    c.add_argument("model", nargs="?", help="registry name (see 'brdf-fit models')")
    c.add_argument("--all", action="store_true", help="check every registered model")
    c.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="parameter value of MODEL (comma-separated for channels); repeatable; "
                        "default: the registry defaults")
    c.add_argument("--check", action="append", metavar="NAME",
                   help="run only this check (repeatable); default: all of "
                        + ", ".join(CHECK_NAMES))
    c.add_argument("--json", action="store_true",
                   help="one record per (model, check): model, check, passed, statistic, ...")
    c.add_argument("--quiet", action="store_true", help="no progress bar")
    c.add_argument("--float32", action="store_true",
                   help="check in float32 (default: float64; tolerances scale with epsilon)")
    c.set_defaults(func=run)
