"""Command-line interface: thin wrappers that parse, call the library, print tables or JSON.

    brdf-fit models [--json]
    brdf-fit eval MODEL [--param NAME=VALUE ...] [--theta-i-deg ...] [--theta-o-deg ...] [--json]
    brdf-fit check MODEL [--param NAME=VALUE ...] [--check NAME ...] [--json]
    brdf-fit check --all [--json]
    brdf-fit synth RECIPE -o FILE [--json]
    brdf-fit fit DATA --model NAME [--fix NAME=VALUE ...] [--init NAME=VALUE ...]
                 [--metric log|cuberoot|relative|absolute|huber|cauchy] [--solver NAME]
                 [--max-zenith-deg X]
                 [--guess grid|none] [--multistart K] [--check NAME ...] [--json]
    brdf-fit fit-batch DATA... --model NAME [--fix ...] [--init ...] [--metric ...]
                 [--guess grid|none] [--skip-bad] [--out FILE.csv|.json] [--json] [--quiet]
                 [--out-dir DIR [--block-size N] [--resume]]
    brdf-fit demo [--out DIR] [--json]
    brdf-fit select DATA [--candidates A,B,..|--family NAME] [--budget X] [--plot PNG] [--json]
    brdf-fit plot MODEL [MODEL ...] [--param NAME=VALUE] [--data FILE [--fit]] -o PNG
    brdf-fit lut dfg -o FILE [--size N] [--masking M] [--layout NAME] [--channels A,B] [--json]
    brdf-fit lut albedo|eavg MODEL --axis NAME=N[:LO:HI] ... [--param NAME=VALUE] -o FILE
    brdf-fit convert phong-to-ggx [--source modified-phong|blinn-phong|...] [--exponents N ...]
                 [--metric log] [--max-zenith-deg 80] [--json]

``synth`` turns a dataset recipe (``.json``/``.toml``, see :mod:`data_synth.recipes`) into a
``.csv`` or ``.npz`` file; ``fit`` reads ``.csv``, ``.npz`` (or its ``.json`` sidecar) or MERL
``.binary`` data and fits a registry model (:func:`brdf_fit.fit.fit`); ``demo`` is the main job on
an embedded default: synthesise noisy gold, fit several models, rank them, convert the Phong
exponent to a GGX width, check the best model, write ``demo.json`` and plots. VALUEs are a number
or comma-separated numbers (one per channel). User errors (bad file, unknown model, parameter,
metric, check) print one line ``brdf-fit: error: ...`` and exit with status 2.

The library is imported inside each command, on purpose: ``brdf-fit --help`` and argument
errors then answer in about 0.1 s instead of paying for JAX first.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys

import numpy as np

from brdf_fit._version import __version__

#: the check names, for --help without importing JAX (tests/cli holds them equal to
#: brdf_fit.verify.checks.CHECKS)
CHECK_NAMES = ("non-negative", "reciprocity", "energy", "ndf-normalisation", "weak-white-furnace",
               "white-furnace", "pdf-normalisation", "sampling-weight", "chi2", "finite")


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {v}")
    return v


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (v > 0 and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return v


def _size(text: str) -> str:
    """A memory size as ``--max-memory`` takes it: checked by the rule that reads it back
    (:func:`brdf_fit.core.limits.parse_size`), kept as text for the environment."""
    from brdf_fit.core.limits import LimitError, parse_size

    try:
        parse_size(text)
    except LimitError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text.strip()


#: seconds after which `brdf-fit fit` stops a large (chunked) fit that has not converged
FIT_TIME_LIMIT = 60.0


class CLIError(Exception):
    """A user error: printed as one line, exit status 2."""


def _registry():
    from brdf_fit import registry

    return registry


def parse_params(items: list[str] | None, entry, flag: str = "--param") -> dict:
    """``NAME=VALUE`` pairs; VALUE is a number or comma-separated numbers (one per channel).
    ``flag`` names the option in error messages."""
    out = {}
    for item in items or []:
        if "=" not in item:
            raise CLIError(f"{flag} expects NAME=VALUE, got {item!r}")
        name, _, text = item.partition("=")
        name = name.strip()
        entry.param(name)  # unknown names raise with the valid list
        try:
            vals = [float(v) for v in text.split(",")]
        except ValueError:
            raise CLIError(
                f"{flag} {name}: {text!r} is not a number or comma-separated numbers"
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


def cmd_catalogue(args) -> int:
    from brdf_fit.verify import catalogue

    if args.write_readme:
        import pathlib

        readme = pathlib.Path(args.write_readme)
        if not readme.is_file():
            raise CLIError(f"{readme}: no such file (--write-readme rewrites the catalogue "
                           "section of an existing README)")
        check_output_file(str(readme), (readme.suffix.lower(),), "--write-readme")
        text = readme.read_text(encoding="utf-8", errors="replace")
        if catalogue.README_BEGIN not in text or catalogue.README_END not in text:
            raise CLIError(f"{readme}: no generated catalogue section (markers "
                           f"{catalogue.README_BEGIN!r} ... {catalogue.README_END!r})")
    records = catalogue.table()
    if args.write_readme:
        changed = catalogue.update_readme(args.write_readme, catalogue.markdown(records))
        print(f"{args.write_readme}: catalogue section {'updated' if changed else 'unchanged'}")
        return 0
    if args.json:
        print(json.dumps({"summary": catalogue.summary(records), "rows": records}, indent=2))
        return 0
    print(catalogue.markdown(records), end="")
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
        self.show(self.done - 1, self.done, self.total, f"{model}: {check}")

    def show(self, filled_count: int, done: int, total: int, text: str) -> None:
        """Write ``[bar] done/total text``, the bar filled to ``filled_count / total``."""
        width = 24
        filled = int(width * filled_count / max(total, 1))
        msg = f"[{'#' * filled}{'-' * (width - filled)}] {done}/{total} {text}"
        if self.tty:
            print("\r" + msg.ljust(78), end="", file=sys.stderr, flush=True)
        else:
            print(msg, file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.enabled and self.tty:
            print("\r" + " " * 78 + "\r", end="", file=sys.stderr, flush=True)


class _StepProgress(_Progress):
    """The steps of a chunked fit (``fit(progress=...)``) on stderr: the stage, the step and
    the loss, one line per step (rewritten in place on a terminal)."""

    def __init__(self, n_samples: int, enabled: bool = True):
        super().__init__(0, enabled)
        self.n_samples = n_samples

    def __call__(self, stage: str, step: int, loss: float) -> None:
        if not self.enabled:
            return
        where = ("a random subset" if stage == "coarse"
                 else f"all {self.n_samples:,} samples")
        msg = f"  step {step} on {where}: loss {loss:.6g}"
        if self.tty:
            print("\r" + msg.ljust(78), end="", file=sys.stderr, flush=True)
        else:
            print(msg, file=sys.stderr, flush=True)


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
    from brdf_fit.verify import checks

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


def _x64() -> None:
    """Synthesis and fitting run in float64 (solver tolerances and standard errors assume it)."""
    import jax

    jax.config.update("jax_enable_x64", True)


def _ext(path: str) -> str:
    import pathlib

    return pathlib.Path(path).suffix.lower()


def check_output_file(path: str, exts: tuple[str, ...], flag: str) -> None:
    """Refuse an output file before any work: a known extension, not a folder, and a folder to
    write it in that exists and is writable (nothing computed is then lost on the write)."""
    import os
    import pathlib

    p = pathlib.Path(path)
    if _ext(path) not in exts:
        raise CLIError(f"{path}: {flag} expects {' or '.join(exts)}")
    if p.is_dir():
        raise CLIError(f"{path}: {flag} names a folder, not a file")
    parent = p.parent if str(p.parent) else pathlib.Path(".")
    if parent.exists() and not parent.is_dir():
        raise CLIError(f"{path}: cannot write: {str(parent)!r} is a file, not a folder")
    if not parent.is_dir():
        raise CLIError(f"{path}: cannot write: folder {str(parent)!r} does not exist")
    if not os.access(parent, os.W_OK) or (p.exists() and not os.access(p, os.W_OK)):
        raise CLIError(f"{path}: cannot write: permission denied")


def check_output_dir(path: str, flag: str) -> None:
    """Refuse an output folder before any work: not an existing file, creatable, writable."""
    import os
    import pathlib

    p = pathlib.Path(path)
    if p.exists() and not p.is_dir():
        raise CLIError(f"{path}: {flag} names an existing file, not a folder")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise CLIError(f"{path}: cannot create the folder ({e.strerror or e})") from None
    if not os.access(p, os.W_OK):
        raise CLIError(f"{path}: cannot write into the folder: permission denied")


def read_data(path: str):
    """:func:`brdf_fit.io.read`, with its errors as one-line CLI errors."""
    from brdf_fit import io
    from brdf_fit.data import DataError

    try:
        return io.read(path)
    except DataError as e:
        raise CLIError(str(e)) from None


def write_data(data, path: str, provenance: dict | None = None) -> list[str]:
    """:func:`brdf_fit.io.write` (``data=None``: only check the format), errors as CLI errors."""
    from brdf_fit import io
    from brdf_fit.data import DataError

    try:
        if data is None:
            io.check_writable_format(path)
            return []
        return io.write(data, path, provenance=provenance)
    except DataError as e:
        raise CLIError(str(e)) from None


def cmd_synth(args) -> int:
    _x64()
    from data_synth.recipes import synthesize

    write_data(None, args.output)  # the format error before the work
    check_output_file(args.output, (".csv", ".npz"), "-o")
    data = synthesize(args.recipe)
    meta = data.metadata
    files = write_data(data, args.output,
                       provenance={"command": "brdf-fit synth", "recipe_file": str(args.recipe)})
    summary = {"files": files, "n_samples": data.n, "channels": list(data.channels),
               "model": meta["model"], "seed": meta["seed"], "plan": meta["plan"]["name"],
               "noise": [m["type"] for m in meta["noise"]] if meta["noise"] else []}
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        noise = ", ".join(summary["noise"]) or "none"
        print(f"wrote {', '.join(files)}: {data.n} samples, {data.n_channels} channel(s) "
              f"({','.join(data.channels)}), model {meta['model']}, seed {meta['seed']}, "
              f"plan {summary['plan']}, noise {noise}")
    return 0


def _check_names(names) -> list[str]:
    from brdf_fit.verify import checks

    for c in names or []:
        if c not in checks.CHECKS:
            raise CLIError(f"unknown check {c!r}; valid checks: {', '.join(checks.CHECKS)}")
    return list(names or [])


def _param_rows(result, channels) -> list[str]:
    """One line per parameter (per channel for channel parameters): value +- standard error."""
    rows = []
    for name, value in result.params.items():
        v = np.atleast_1d(np.asarray(value, float))
        se = result.stderr.get(name)
        se = None if se is None else np.atleast_1d(np.asarray(se, float))
        note = getattr(result, "stderr_note", {}).get(name)
        note = None if note is None else np.atleast_1d(np.asarray(note, object))
        flagged = set(getattr(result, "undetermined", ()))
        for j, x in enumerate(v):
            label = name if v.size == 1 else (
                f"{name}[{channels[j]}]" if len(channels) == v.size else f"{name}[{j}]")
            why = str(note[j]) if note is not None and note.size == v.size else ""
            err = "(fixed)" if name in result.fixed else (
                "" if se is None else
                f"stderr undefined: {why or 'not finite'}" if not np.isfinite(se[j]) else
                f"+- {se[j]:.3g}" + ("  UNDETERMINED" if label in flagged else ""))
            rows.append(f"  {label:<16} {x:12.6g}  {err}")
    return rows


def _print_undetermined(labels, indent: str = "  ") -> None:
    """The fit's undetermined entries, with the rule that flags them (or nothing)."""
    from brdf_fit.fitting.problem import UNDETERMINED_RULE

    if labels:
        print(f"{indent}undetermined: {', '.join(labels)} ({UNDETERMINED_RULE}; fix them "
              "(--fix) or measure where they matter)")


def _print_fit(result, data, path: str) -> None:
    print(f"{result.model_name} fitted to {path}: {result.n_samples} samples x "
          f"{data.n_channels} channel(s) ({','.join(data.channels)}), metric {result.metric}"
          + (" (residuals in units of sigma)" if data.sigma is not None else ""))
    print(f"  {'parameter':<16} {'value':>12}  standard error")
    for row in _param_rows(result, data.channels):
        print(row)
    if result.at_bound:
        print(f"  at an interval end: {', '.join(result.at_bound)} (a limit, not an optimum; "
              "no standard error)")
    _print_undetermined(result.undetermined)
    status = "yes" if result.converged else f"NO ({result.message})"
    print(f"converged: {status}; steps: {result.steps}; starts: {result.starts}; "
          f"residual rms: {result.residual_rms:.6g}; time: {result.seconds:.2f} s")
    if result.checks:
        print()
        _print_check_table(result.checks)


def cmd_fit(args) -> int:
    _x64()
    models = [m.strip() for m in args.model.split(",") if m.strip()]
    if len(args.data) > 1 or len(models) > 1 or args.table is not None or args.shard:
        return _fit_database(args, models)
    if args.processes is not None:
        raise CLIError("--processes shares a database run (several files or models, --table)")
    args.data = args.data[0]
    from brdf_fit.fitting.single import fit

    reg = _registry()
    entry = _target_entry(reg, args.model, args.target)  # fails before the data are read
    export_kind = _export_kind(args.export, args.target)
    fix = parse_params(args.fix, entry, "--fix")
    init = parse_params(args.init, entry, "--init")
    both = sorted(set(fix) & set(init))
    if both:
        raise CLIError(f"parameter(s) {', '.join(both)} given both --fix and --init")
    checks = _check_names(args.check)
    if args.multistart < 1:
        raise CLIError(f"--multistart must be >= 1, got {args.multistart}")
    data = read_data(args.data)
    if args.max_samples is not None:
        if args.max_samples < 1:
            raise CLIError(f"--max-samples must be >= 1, got {args.max_samples}")
        if data.n > args.max_samples:
            rng = np.random.default_rng(args.seed)
            data = data.subset(np.sort(rng.choice(data.n, args.max_samples, replace=False)))
    if not args.quiet:  # one status line: a first fit spends most of its time compiling
        print(f"fitting {entry.name} to {data.n} samples x {data.n_channels} channels "
              f"(metric {args.metric}, {args.multistart} start(s)) ...", file=sys.stderr,
              flush=True)
    progress = _StepProgress(data.n, enabled=not args.quiet)
    try:
        result = fit(data, entry.name, fix=fix, init=init, metric=args.metric,
                     solver=args.solver, cos_weight=args.cos_weight,
                     max_zenith_deg=args.max_zenith_deg, multistart=args.multistart,
                     seed=args.seed, max_steps=args.max_steps, checks=checks, guess=args.guess,
                     time_limit=args.time_limit, progress=progress)
    finally:
        progress.close()
    exported, write_error = None, None
    if export_kind is not None:
        try:
            exported = _write_export(export_kind, args.export, entry.name, result.params, data,
                                     name=os.path.splitext(os.path.basename(args.data))[0])
        except OSError as e:  # the fit is printed below all the same: nothing computed is lost
            write_error = (f"--export {args.export}: cannot write ({e.strerror or e}); the "
                           "fit is printed instead")
    if args.json:
        doc = result.to_dict()
        if exported is not None:
            doc["export"] = exported
        if write_error is not None:
            doc.update(error=write_error, exit_status=1)
        print(json.dumps(doc, indent=2))
    else:
        _print_fit(result, data, args.data)
        if exported is not None:
            err = exported["error"]
            print(f"export: {exported['target']} {exported['method']} "
                  + ("(not verified)" if err is None else f"(round-trip error {err:.3g})")
                  + f": {exported['note']}")
            print(f"wrote {args.export}")
    if write_error is not None:
        print(f"brdf-fit: error: {write_error}", file=sys.stderr)
        return 1
    failed = [c for c in result.checks if not c.ok]
    return 0 if result.converged and not failed else 1

#: data file extensions a folder given to `fit` is searched for
_DATA_EXTS = (".binary", ".csv", ".npz")


def _database_files(items, exclude=()) -> list[str]:
    """The data files of ``fit``'s positional arguments: a folder stands for its data files
    (:data:`_DATA_EXTS`, sorted) but the ``exclude`` files (the run's own table, which may be
    written into the folder it reads); a file named twice is fitted once."""
    skip = {os.path.abspath(x) for x in exclude}
    out = []
    for item in items:
        if os.path.isdir(item):
            found = sorted(os.path.join(item, n) for n in os.listdir(item)
                           if n.lower().endswith(_DATA_EXTS)
                           and os.path.abspath(os.path.join(item, n)) not in skip)
            if not found:
                raise CLIError(f"{item}: a folder with no data file ({', '.join(_DATA_EXTS)})")
            out += found
        else:
            out.append(item)
    return list(dict.fromkeys(out))


def _parse_shard(text: str) -> tuple[int, int]:
    try:
        i, n = (int(x) for x in text.split("/"))
    except ValueError:
        raise CLIError(f"--shard must be I/N (e.g. 0/2), got {text!r}") from None
    if not (n >= 1 and 0 <= i < n):
        raise CLIError(f"--shard {text}: need 0 <= I < N")
    return i, n


def _fit_database(args, models) -> int:
    """:func:`_fit_database_run` holding the run lock of the table's parts folder
    (:mod:`brdf_fit.core.runlock`), except for one shard of a run (``--shard``: the launcher
    holds it, or the machines of a shared folder each run their own share)."""
    from brdf_fit.fitting.database import PARTS_SUFFIX

    parent = os.path.dirname(os.path.abspath(args.table)) if args.table else None
    if args.shard or args.table is None or not os.path.isdir(parent):
        return _fit_database_run(args, models)  # (a missing folder is its error to report)
    from brdf_fit.core.runlock import hold

    with hold(args.table + PARTS_SUFFIX):
        return _fit_database_run(args, models)


def _fit_database_run(args, models) -> int:
    """``brdf-fit fit FILES --model A,B --table OUT.csv``: every file fitted to every model
    (:mod:`brdf_fit.fitting.database`), kept pair by pair, resumable, over several processes
    with ``--processes N`` (or ``--shard I/N`` per machine on a shared folder)."""
    import time

    from brdf_fit.fitting import database

    if args.table is None:
        raise CLIError("several files or models: name the table to write with --table OUT.csv")
    if not args.table.lower().endswith(".csv"):
        raise CLIError(f"--table {args.table}: the table is a .csv file (its .json is written "
                       "beside it)")
    for flag, given in (("--export", args.export), ("--target", args.target),
                        ("--check", args.check)):
        if given:
            raise CLIError(f"{flag} is for one fit; a database run writes a table")
    if (args.fix or args.init) and len(models) > 1:
        raise CLIError("--fix and --init name one model's parameters: give one --model with "
                       "them")
    check_output_file(args.table, (".csv",), "--table")
    reg = _registry()
    entries = [reg.get(m) for m in models]  # an unknown name fails before any file is read
    files = _database_files(args.data, exclude=(args.table,))
    fix = parse_params(args.fix, entries[0], "--fix") if args.fix else {}
    init = parse_params(args.init, entries[0], "--init") if args.init else {}
    options = {"metric": args.metric, "cos_weight": args.cos_weight,
               "max_zenith_deg": args.max_zenith_deg, "multistart": args.multistart,
               "seed": args.seed, "max_steps": args.max_steps, "guess": args.guess,
               "time_limit": args.time_limit,
               "fix": {k: np.asarray(v).tolist() for k, v in fix.items()},
               "init": {k: np.asarray(v).tolist() for k, v in init.items()}}
    if args.max_samples is not None:  # part of each pair's identity, not a fit() option
        options["max_samples"] = args.max_samples
    folder = args.table + database.PARTS_SUFFIX
    names = [e.name for e in entries]
    shard = _parse_shard(args.shard) if args.shard else None
    if shard is not None and args.processes is not None:
        raise CLIError("--processes starts its own shards: not with --shard")
    before = None
    if args.processes is not None and args.processes > 1:
        before = database.count_finished(files, names, folder, options)
        _database_processes(args)
    max_samples = args.max_samples

    def reader(path):
        from brdf_fit import io

        data = io.read(path)  # a DataError is that file's failure, reported in the table's run
        if max_samples is not None and data.n > max_samples:
            rng = np.random.default_rng(args.seed)
            data = data.subset(np.sort(rng.choice(data.n, max_samples, replace=False)))
        return data

    fit_options = {**{k: v for k, v in options.items() if k != "max_samples"}, "fix": fix,
                   "init": init}

    def progress(done, total, text):
        if not args.quiet:
            print(f"[{done}/{total}] {text}", file=sys.stderr, flush=True)

    t0 = time.perf_counter()
    try:
        run = database.fit_database(files, names, folder, fit_options=fit_options,
                                    identity=options, shard=shard, progress=progress,
                                    reader=reader)
    except (KeyboardInterrupt, _Terminated) as e:
        kept = database.count_finished(files, names, folder, options)
        print(f"brdf-fit: {'interrupted' if isinstance(e, KeyboardInterrupt) else 'terminated'}"
              f": {kept} finished pair(s) kept in {folder}; the same command continues the run",
              file=sys.stderr)
        return 130 if isinstance(e, KeyboardInterrupt) else 143
    if before is not None:  # the processes fitted what this run found done, but `before`
        run.fitted_now += run.already_done - before
        run.already_done = before
    if shard is not None:  # one share of a run: the table is assembled by a run without it
        if not args.quiet:
            print(f"shard {args.shard}: {run.fitted_now} fitted now, {run.already_done} done "
                  f"before, {run.failed} failed", file=sys.stderr)
        return 0 if not run.failed else 1
    meta = {"files": files, "models": names, "options": options,
            "pairs": run.total, "finished": len(run.rows), "failures": run.failures}
    written = database.write_table(args.table, run.rows, meta)
    figure = os.path.splitext(args.table)[0] + ".png"
    try:
        from brdf_fit.plot import database_errors

        if run.rows:
            database_errors(run.rows).savefig(figure, dpi=110)
            written.append(figure)
    except ImportError:
        pass  # matplotlib is an extra: the table stands without its figure
    seconds = time.perf_counter() - t0
    not_conv = [f"{r['material']} {r['model']}" for r in run.rows if not r["converged"]]
    if args.json:
        print(json.dumps({**meta, "fitted_now": run.fitted_now,
                          "already_done": run.already_done, "failed": run.failed,
                          "not_converged": not_conv, "written": written,
                          "seconds": round(seconds, 3), "rows": run.rows}, indent=1))
    else:
        _print_database(run, names)
        print(f"{run.fitted_now} fitted now + {run.already_done} done before + {run.failed} "
              f"failed = {run.total} pairs ({len(files)} files x {len(names)} models) in "
              f"{seconds:.1f} s; wrote {', '.join(written)}")
        for f in run.failures:
            print(f"  failed: {f}")
        if not_conv:
            print(f"  not converged: {', '.join(not_conv)}")
    return 0 if not run.failed and not not_conv else 1


def _print_database(run, models) -> None:
    """The relative RMS radiance error per material (rows) and model (columns)."""
    by = {(r["material"], r["model"]): r for r in run.rows}
    materials = list(dict.fromkeys(r["material"] for r in run.rows))
    width = max([8, *(len(m) for m in materials)])
    print(f"{'rel. RMS':<{width}} " + " ".join(f"{m:>14}" for m in models))
    for mat in materials:
        cells = []
        for m in models:
            r = by.get((mat, m))
            cells.append("-" if r is None else
                         f"{r['errors']['rel_rms']:.4g}{'' if r['converged'] else '*'}")
        print(f"{mat:<{width}} " + " ".join(f"{c:>14}" for c in cells))
    if any(not r["converged"] for r in run.rows):
        print("(* not converged)")


#: seconds a stopped launcher's processes get to end on SIGTERM before they are killed (a
#: process inside an XLA computation or a barrier of JAX's coordination service answers only
#: when it returns: 12-42 s measured; every block a process finished is on disk already)
STOP_GRACE_S = 3.0


def _stop_children(procs) -> None:
    """End every process of ``procs`` (subprocess.Popen): SIGTERM, then SIGKILL for whichever
    is still running after :data:`STOP_GRACE_S`; waits for all. The launchers start their
    processes in sessions of their own, so a Ctrl-C at the terminal (SIGINT to the foreground
    group) reaches the launcher alone, which stops them here and prints the one line (each
    process printed its own traceback before)."""
    import subprocess
    import time

    for p in procs:
        if p.poll() is None:
            p.terminate()
    deadline = time.monotonic() + STOP_GRACE_S
    for p in procs:
        try:
            p.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def _child_argv(args, with_value: tuple[str, ...], flags: tuple[str, ...]) -> list[str]:
    """This command's arguments for the processes a launcher starts: without the options
    ``with_value`` (and their values, in either spelling) and the ``flags``."""
    argv, skip = [], False
    for a in sys.argv[1:] if getattr(args, "_argv", None) is None else args._argv:
        if skip:
            skip = False
            continue
        if a in with_value:
            skip = True
            continue
        if a.startswith(tuple(f"{o}=" for o in with_value)) or a in flags:
            continue
        argv.append(a)
    return argv


def _database_processes(args) -> None:
    """``--processes N``: N local processes, each fitting every N-th pair (``--shard I/N``);
    returns when all have ended (the caller then assembles the table, fitting whatever a
    process could not finish). Ctrl-C stops them all."""
    import subprocess

    argv = _child_argv(args, ("--processes",), ("--json", "--quiet"))
    n = args.processes
    procs = [subprocess.Popen([sys.executable, "-m", "brdf_fit.cli", *argv, "--shard",
                               f"{i}/{n}", *(["--quiet"] if args.quiet else [])],
                              stdout=subprocess.DEVNULL, start_new_session=True)
             for i in range(n)]
    try:
        for p in procs:
            p.wait()
    except BaseException:  # Ctrl-C or SIGTERM (_Terminated): no process outlives this one
        _stop_children(procs)
        raise


#: export targets by output extension
_EXPORT_EXT = {".xml": "mitsuba", ".gltf": "gltf"}


def _target_entry(reg, model: str, target: str | None):
    """The registry entry ``model`` names; with ``--target T`` it must be written to T with no
    loss, and a bare plugin name is looked up as ``T-NAME`` (``roughplastic`` ->
    ``mitsuba-roughplastic``)."""
    if target is None:
        return reg.get(model)
    from brdf_fit.selection.selector import (
        TARGETS,
        anisotropic_candidates,
        exports_exactly,
        target_candidates,
    )

    if target not in TARGETS:
        raise CLIError(f"--target must be one of {', '.join(TARGETS)}, got {target!r}")
    for name in (model, f"{target}-{model}"):
        try:
            e = reg.get(name)
        except KeyError:
            continue
        if exports_exactly(e.name, target):
            return e
    models = (*target_candidates(target), *anisotropic_candidates(target))
    raise CLIError(f"--target {target}: {model!r} is not one of its models (written to "
                   f"{target} as fitted): {', '.join(models)}")


def _export_kind(path: str | None, target: str | None) -> str | None:
    if path is None:
        return None
    ext = os.path.splitext(path)[1].lower()
    kind = _EXPORT_EXT.get(ext)
    if kind is None:
        raise CLIError(f"--export: {path!r} must end in .xml (Mitsuba 3) or .gltf (glTF 2.0)")
    if target is not None and kind != target:
        raise CLIError(f"--export {path}: a {ext} file is a {kind} export, but --target is "
                       f"{target}")
    check_output_file(path, (ext,), "--export")
    return kind


def _write_export(kind: str, path: str, model: str, params: dict, data, name: str) -> dict:
    """Write ``model`` at ``params`` to ``path`` (Mitsuba XML or glTF), its round trip
    measured on the data's own geometry; returns what was written."""
    p = {k: np.asarray(v, np.float64) for k, v in params.items()}
    geometry = (data.wi, data.wo)
    if kind == "mitsuba":
        from brdf_fit.convert import mitsuba as cmi

        try:
            e = cmi.to_mitsuba(model, p, name=name, geometry=geometry)
        except cmi.ExportError as exc:
            raise CLIError(f"--export: {exc}") from None
        text = cmi.scene_document([(name, e.scene_dict)],
                                  comment=f"brdf_fit fit: {model} fitted to {name}")
        from brdf_fit.core.atomic import write_text_atomic

        write_text_atomic(path, text)
    else:
        from brdf_fit.convert import gltf as cg

        try:
            e = cg.to_gltf(model, p, name=name, geometry=geometry)
        except cg.ExportError as exc:
            raise CLIError(f"--export: {exc}") from None
        cg.write_gltf(path, [e])
    return {"target": kind, "path": path, "method": e.method, "error": e.error,
            "note": e.note}


class _BatchProgress(_Progress):
    """A bar of finished problems on stderr for fit_batch's ``progress`` callback."""

    def __init__(self, label: str, enabled: bool = True):
        super().__init__(0, enabled)
        self.label = label

    def __call__(self, done: int, total: int, stage: str) -> None:
        if self.enabled:
            self.show(done, done, total, f"{self.label}: {stage}")


def _read_many(paths, skip_bad: bool):
    """Read every file; a bad one is reported with its path. Without ``skip_bad`` any bad file
    stops the command before anything is fitted (nothing computed is lost)."""
    good, bad = [], []
    for path in paths:
        try:
            data = read_data(path)
            data.validate()
            good.append((path, data))
        except _user_errors() as e:
            bad.append(f"{path}: {e}" if not str(e).startswith(path) else str(e))
    if bad and not skip_bad:
        raise CLIError(f"{len(bad)} of {len(paths)} file(s) could not be read (--skip-bad fits "
                       "the others):\n  " + "\n  ".join(bad))
    if not good:
        raise CLIError("no readable data file:\n  " + "\n  ".join(bad))
    return good, bad


def _batch_rows(paths, res, channels) -> list[dict]:
    from brdf_fit.fitting.problem import entry_labels  # loaded with fit_batch already
    from brdf_fit.fitting.single import json_floats

    rows = []
    und = res.undetermined
    for b, path in enumerate(paths):
        rows.append({
            "file": path, "model": res.model_name,
            "params": {k: np.asarray(v[b]).tolist() for k, v in res.params.items()},
            "stderr": {k: json_floats(v[b]) for k, v in res.stderr.items()},
            "stderr_note": {k: np.asarray(v[b]).tolist() for k, v in res.stderr_note.items()
                            if (np.asarray(v[b]) != "").any()},
            "converged": bool(res.converged[b]), "steps": int(res.steps[b]),
            "metric": res.metric, "residual_rms": float(res.residual_rms[b]),
            "n_samples": int(res.n_samples[b]), "channels": list(channels),
            "at_bound": [k for k, v in res.at_bound.items() if np.asarray(v[b]).any()],
            "undetermined": [
                lab for k, v in und.items()
                for lab, bad in zip(entry_labels(k, np.shape(v[b]), channels),
                                    np.asarray(v[b]).reshape(-1), strict=True) if bad],
        })
    return rows


#: a batch member is flagged when its residual rms exceeds this many times the batch median
RMS_FLAG_FACTOR = 10.0
#: ... or when it has fewer than this many samples per free scalar parameter (a 3-sample file
#: is fitted exactly, with small standard errors, and no other flag catches it)
MIN_SAMPLES_PER_PARAM = 3


def _flag_rows(rows) -> None:
    """Add ``flags`` to each fit-batch row: "not converged", "at bound", "undetermined: ..."
    (:data:`brdf_fit.fitting.problem.UNDETERMINED_RULE`), "rms > 10x median" (the median over
    every file of the run) and "few samples"."""
    if not rows:
        return
    med = float(np.median([r["residual_rms"] for r in rows]))
    for r in rows:
        k = sum(np.asarray(v).size for v in r["params"].values())
        flags = []
        if not r["converged"]:
            flags.append("not converged")
        if r["at_bound"]:
            flags.append("at bound")
        if r.get("undetermined"):
            flags.append(f"undetermined: {', '.join(r['undetermined'])}")
        if med > 0 and r["residual_rms"] > RMS_FLAG_FACTOR * med:
            flags.append(f"rms > {RMS_FLAG_FACTOR:g}x median")
        if r["n_samples"] < MIN_SAMPLES_PER_PARAM * k:
            flags.append(f"few samples ({r['n_samples']} for {k} parameters)")
        r["flags"] = flags


def _note_text(v) -> str:
    """A stderr_note entry (one reason, or one per channel; "" where defined) as text."""
    a = [str(x) for x in np.atleast_1d(np.asarray(v, object))]
    return a[0] if len(set(a)) == 1 else ",".join(x or "-" for x in a)


def _write_batch_table(rows, path: str) -> None:
    import csv

    if _ext(path) == ".json":
        with open(path, "w") as fh:
            json.dump(rows, fh, indent=1)
        return
    if _ext(path) != ".csv":
        raise CLIError(f"{path}: --out expects .csv or .json")
    cols = ["file", "converged", "steps", "residual_rms", "n_samples"]
    flat = []
    for r in rows:
        d = {k: r[k] for k in cols}
        for kind in ("params", "stderr"):
            for name, v in r[kind].items():
                a = np.atleast_1d(np.asarray(v, float))
                for j, x in enumerate(a):
                    key = name if a.size == 1 else f"{name}_{r['channels'][j].lower()}" if (
                        len(r["channels"]) == a.size) else f"{name}_{j}"
                    d[key if kind == "params" else f"stderr_{key}"] = f"{x:.10g}"
        d["at_bound"] = ";".join(r["at_bound"])
        d["undetermined"] = ";".join(r.get("undetermined", []))
        d["stderr_note"] = ";".join(f"{k}: {_note_text(v)}" for k, v in r["stderr_note"].items())
        d["flags"] = ";".join(r.get("flags", []))
        flat.append(d)
    fields = list(dict.fromkeys(k for d in flat for k in d))
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields)
        w.writeheader()
        w.writerows(flat)


def _geometry(ds):
    """``(wi, wo)`` of data sets ``ds`` for fit_batch: one (M, 3) pair when every file has
    exactly the first one's directions (a gonioreflectometer's texels), which fit_batch keeps
    once and for which it uses its finer shared-geometry guess; else stacked (B, M, 3)."""
    wi0, wo0 = ds[0].wi, ds[0].wo
    if all(np.array_equal(d.wi, wi0) and np.array_equal(d.wo, wo0) for d in ds[1:]):
        return wi0, wo0
    return np.stack([d.wi for d in ds]), np.stack([d.wo for d in ds])


def _fit_batch_streamed(args, entry, fix, init) -> int:
    """:func:`_fit_batch_run` holding the output folder's run lock
    (:mod:`brdf_fit.core.runlock`: a second run on the folder stops at once, naming the
    holder), except in a process that joins a multi-process run (its launcher or lead holds the
    folder; on several machines the lock is not taken, as each machine sees its own)."""
    if (getattr(args, "_locked", False) or args.coordinator or args.cluster
            or args.process_id is not None):
        return _fit_batch_run(args, entry, fix, init)
    from brdf_fit.core.runlock import hold

    with hold(_check_out_dir(args)):
        args._locked = True
        return _fit_batch_run(args, entry, fix, init)


def _fit_batch_run(args, entry, fix, init) -> int:
    """``fit-batch --out-dir DIR``: the files are read block by block (``--block-size``
    files at a time, default from a 512 MB budget) and fitted by
    :func:`brdf_fit.fitting.stream.fit_stream`, which writes each finished block to DIR
    (``block_*.npz``, ``manifest.json``; ``files.txt`` lists the files in order). A killed run
    restarted with ``--resume`` fits only the blocks not written yet. All files must be
    readable and share one sample count, channel count and sigma-or-not (checked per block;
    the blocks written before a bad file are kept)."""
    import hashlib

    from brdf_fit.fitting.stream import fit_stream

    if args.skip_bad:
        raise CLIError("--skip-bad is not available with --out-dir (every file is needed)")
    if args.processes is not None and args.processes > 1:
        return _fit_batch_processes(args)
    if args.values is not None:
        return _fit_batch_values(args, entry, fix, init, fit_stream)
    if args.images is not None:
        return _fit_batch_images(args, entry, fix, init, fit_stream)
    if not args.data:
        raise CLIError("fit-batch needs data files (or --values FILE.npy --geometry FILE.npz "
                       "with --out-dir)")
    shard, sync = _join_run(args)
    out = _check_out_dir(args)
    if args.out is not None:
        check_output_file(args.out, (".csv", ".json"), "--out")
    _check_new_run(args, out)
    paths = list(args.data)
    first = read_data(paths[0])
    first.validate()
    shape = (first.n, first.channels, first.sigma is not None)

    def source(s, e):
        blk = []
        for path in paths[s:e]:
            d = first if path == paths[0] and s == 0 else read_data(path)
            d.validate()
            if (d.n, d.channels, d.sigma is not None) != shape:
                raise CLIError(f"{path}: {d.n} samples, channels {','.join(d.channels)}"
                               f"{', sigma' if d.sigma is not None else ''}; --out-dir needs "
                               f"every file like {paths[0]} ({shape[0]} samples, channels "
                               f"{','.join(shape[1])}{', sigma' if shape[2] else ''})")
            blk.append(d)
        wi, wo = _geometry(blk)
        return {"wi": wi, "wo": wo, "values": np.stack([d.value for d in blk]),
                "weight": np.stack([d.weight for d in blk]),
                "sigma": np.stack([d.sigma for d in blk]) if shape[2] else None}

    digest = hashlib.sha256("\n".join(paths).encode()).hexdigest()
    bar = _BatchProgress(f"{entry.name}, {len(paths)} file(s) of {first.n} samples",
                         enabled=not args.quiet)
    try:
        res = fit_stream(source, entry.name, out, n_problems=len(paths),
                         meta={"files": digest, "n_files": len(paths)}, progress=bar,
                         **_stream_kw(args, fix, init, shard, sync))
    finally:
        bar.close()
    if shard is not None and shard[0] != 0:
        return 0  # the lead (process 0) reports the run
    (out / "files.txt").write_text("\n".join(paths) + "\n")
    full = res.result()
    rows = _batch_rows(paths, full, first.channels)
    _flag_rows(rows)
    if args.out is not None:
        _write_batch_table(rows, args.out)
    return _stream_report(
        args, entry, res, out, full, f"{len(paths)} file(s)", "files.txt",
        {"files": len(paths),
         "not_converged": [r["file"] for r in rows if not r["converged"]][:100]}, args.out)


def _stream_report(args, entry, res, out, full, what, wrote, extra, table=None,
                   measured=None) -> int:
    """The summary of a streamed fit-batch run (JSON or two lines) and its exit status: 0
    when every problem converged, else 1. ``what``: the problems in words; ``wrote``: what the
    folder holds besides the blocks and the manifest; ``extra``: the JSON's own fields;
    ``table``: the per-file table written (--out), if any; ``measured``: the problems that
    count (a mask; default all)."""
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
        print(json.dumps(summary, indent=2))
    else:
        print(f"{entry.name} fitted to {what}, metric {args.metric}, in "
              f"{res.n_blocks} block(s) of {res.block_size} ({len(res.fitted)} fitted now, "
              f"{len(res.skipped)} already written); converged {100 * conv:.2f}%")
        print(f"wrote {out}/ (block_*.npz, manifest.json, {wrote})")
        if table is not None:
            print(f"wrote {table}")
    return 0 if conv == 1.0 else 1


def _fit_batch_setup(args):
    reg = _registry()
    entry = reg.get(args.model)
    fix = parse_params(args.fix, entry, "--fix")
    init = parse_params(args.init, entry, "--init")
    both = sorted(set(fix) & set(init))
    if both:
        raise CLIError(f"parameter(s) {', '.join(both)} given both --fix and --init")
    return entry, fix, init


def _stream_kw(args, fix, init, shard, sync) -> dict:
    """fit_stream's keywords from fit-batch's options, the same for files and value arrays (a
    process of a multi-process run always resumes: the lead settled the folder)."""
    return {"block_size": args.block_size, "resume": args.resume or shard is not None,
            "shard": shard, "sync": sync, "fix": fix, "init": init, "metric": args.metric,
            "cos_weight": args.cos_weight, "max_zenith_deg": args.max_zenith_deg,
            "max_steps": args.max_steps, "guess": args.guess}


def _fit_batch_values(args, entry, fix, init, fit_stream) -> int:
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
    out = _check_out_dir(args)
    _check_new_run(args, out)
    shard, sync = _join_run(args)
    bar = _BatchProgress(f"{entry.name}, {values.shape[0]} problems of {values.shape[1]} samples",
                         enabled=not args.quiet)
    try:
        res = fit_stream(values, entry.name, out, wi=wi, wo=wo,
                         meta={"values": str(args.values), "shape": values.shape}, progress=bar,
                         **_stream_kw(args, fix, init, shard, sync))
    finally:
        bar.close()
    if shard is not None and shard[0] != 0:
        return 0  # the lead (process 0) reports the run
    from brdf_fit.io.stack import result_maps, write_maps

    full = res.result()
    arrays = result_maps(full)
    write_maps(out / "maps", arrays)
    return _stream_report(
        args, entry, res, out, full, f"{values.shape[0]} problems", "maps/*.npy",
        {"problems": int(values.shape[0]), "maps": sorted(f"maps/{n}.npy" for n in arrays)})


def _fit_batch_images(args, entry, fix, init, fit_stream) -> int:
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
    out = _check_out_dir(args)
    _check_new_run(args, out)
    shard, sync = _join_run(args)
    lead = shard is None or shard[0] == 0
    vpath = out / "values.npy"
    if lead:
        out.mkdir(exist_ok=True)
        bar = _BatchProgress(f"reading {stack.n_images} images of {stack.shape[1]}x"
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
    bar = _BatchProgress(f"{entry.name}, {H}x{W} texels of {stack.n_images} images",
                         enabled=not args.quiet)
    try:
        res = fit_stream(source, entry.name, out, n_problems=stack.n_texels, wi=stack.wi,
                         wo=stack.wo, meta=stack.fingerprint(), progress=bar,
                         **_stream_kw(args, fix, init, shard, sync))
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
    written = write_maps(out / "maps", maps, exr=exr, attributes=attributes)
    if not exr and not args.json:
        print("OpenEXR is not installed: maps written as .npy only (pip install OpenEXR)",
              file=sys.stderr)
    what = f"{H}x{W} texels" + (f" ({int(empty.sum())} without a finite pixel: not fitted, "
                                  "NaN in the maps)" if empty.any() else "")
    return _stream_report(
        args, entry, res, out, full, what, "values.npy, maps/*.npy"
        + (", maps/*.exr" if exr else ""),
        {"problems": stack.n_texels, "shape": [H, W], "images": stack.n_images,
         "unmeasured": int(empty.sum()),
         "maps": sorted(str(p.relative_to(out)) for p in written)}, measured=~empty)


def _join_run(args):
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


def _check_out_dir(args):
    """``--out-dir`` as a path, refused before any work when it names a file or its parent
    folder does not exist."""
    import pathlib

    out = pathlib.Path(args.out_dir)
    if out.exists() and not out.is_dir():
        raise CLIError(f"{args.out_dir}: --out-dir names an existing file, not a folder")
    parent = out.parent if str(out.parent) else pathlib.Path(".")
    if not out.exists() and parent.exists() and not parent.is_dir():
        raise CLIError(f"{args.out_dir}: cannot write: {str(parent)!r} is a file, not a folder")
    if not out.exists() and not parent.is_dir():
        raise CLIError(f"{args.out_dir}: cannot write: folder {str(parent)!r} does not exist")
    return out


def _check_new_run(args, out) -> None:
    """A folder holding a previous run (its manifest) is refused without ``--resume``; a process
    joining a multi-process run is exempt (its lead, process 0, settles the folder)."""
    if (out / "manifest.json").exists() and not args.resume and not (
            args.coordinator or args.cluster):
        raise CLIError(f"{args.out_dir}: holds a previous run; --resume continues it (or "
                       "choose a new folder)")


def _fit_batch_processes(args) -> int:
    """``fit-batch --out-dir DIR --processes N``: N local processes on one machine, joined by
    JAX's multi-process runtime (process 0 hosts the coordinator on a free local port); this
    process launches them, shows the blocks written, and reports the folder when all are done."""
    import socket
    import subprocess
    import time

    out = _check_out_dir(args)
    _check_new_run(args, out)
    if args.coordinator or args.cluster or args.process_id is not None:
        raise CLIError("--processes starts its own processes: not with --coordinator/--cluster")
    if args.images is not None:  # a bad description is reported once, here, not by each child
        from brdf_fit.data import DataError
        from brdf_fit.io.stack import read_stack

        try:
            read_stack(args.images)
        except (DataError, ImportError) as e:
            raise CLIError(str(e)) from None
    with socket.socket() as sock:  # a free port for process 0's coordination service
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    # the report (and its table, --out) is this process's
    argv = _child_argv(args, ("--processes", "--out"), ("--resume", "--json", "--quiet"))
    n = args.processes
    before = {int(p.stem.split("_")[1]) for p in out.glob("block_*.npz")} if out.is_dir() else set()
    procs = [subprocess.Popen([sys.executable, "-m", "brdf_fit.cli", *argv, "--quiet",
                               "--coordinator", f"127.0.0.1:{port}", "--num-processes", str(n),
                               "--process-id", str(i)], stdout=subprocess.DEVNULL,
                              start_new_session=True)
             for i in range(n)]
    t0 = time.perf_counter()
    tty, last, shown = sys.stderr.isatty(), -1.0, None
    try:
        while any(p.poll() is None for p in procs):
            k = len(list(out.glob("block_*.npz"))) if out.is_dir() else 0
            now = time.perf_counter() - t0
            # a terminal: one line rewritten; a log: a line when a block lands, or every 10 s
            if not args.quiet and (tty or k != shown or now - last >= 10):
                msg = f"fit-batch: {n} processes, {k} block(s) written, {now:.0f} s"
                print("\r" + msg if tty else msg, end="" if tty else "\n", file=sys.stderr,
                      flush=True)
                last, shown = now, k
            time.sleep(0.5)
    except BaseException:  # Ctrl-C or SIGTERM (_Terminated): no process outlives this one
        _stop_children(procs)
        raise
    finally:
        if not args.quiet and tty:
            print(file=sys.stderr)
    codes = [p.wait() for p in procs]
    # 1 is a finished run with some fit not converged (the report below says which); 2 an
    # error, a negative status a signal
    if any(c not in (0, 1) for c in codes):
        bad = ", ".join(f"process {i}: exit status {c}" for i, c in enumerate(codes)
                        if c not in (0, 1))
        raise CLIError(f"{bad}; the blocks written are kept in {args.out_dir}: --resume "
                       "completes the run")
    # every block is written: the report is a resumed run that fits nothing; its counts are
    # this launch's (the blocks the processes wrote are "fitted now", not "already written")
    args.processes, args.resume = None, True
    args._blocks_before = before
    return _fit_batch_streamed(args, *_fit_batch_setup(args))


def cmd_fit_batch(args) -> int:
    _x64()
    from brdf_fit.fitting.batch import fit_batch

    entry, fix, init = _fit_batch_setup(args)
    if args.values is not None and args.out_dir is None:
        raise CLIError("--values needs --out-dir (the streamed path writes the maps there)")
    if args.images is not None and args.out_dir is None:
        raise CLIError("--images needs --out-dir (the streamed path writes the maps there)")
    if args.out_dir is None and not args.data:
        raise CLIError("fit-batch needs data files")
    if args.out_dir is not None:
        return _fit_batch_streamed(args, entry, fix, init)
    if args.resume or args.block_size is not None:
        raise CLIError("--resume and --block-size need --out-dir (the streamed path)")
    if (args.processes or args.coordinator or args.cluster or args.num_processes
            or args.process_id is not None):
        raise CLIError("several processes need --out-dir (the streamed path)")
    if args.out is not None:
        check_output_file(args.out, (".csv", ".json"), "--out")
    good, bad = _read_many(args.data, args.skip_bad)
    # one batch per (sample count, channels, sigma or not): fit_batch stacks equal shapes
    groups: dict = {}
    for path, d in good:
        groups.setdefault((d.n, d.channels, d.sigma is not None), []).append((path, d))
    rows = []
    for (n, channels, has_sigma), items in groups.items():
        paths = [p for p, _ in items]
        label = f"{entry.name}, {len(items)} file(s) of {n} samples"
        progress = _BatchProgress(label, enabled=not args.quiet)
        try:
            res = fit_batch(
                *_geometry([d for _, d in items]),
                np.stack([d.value for _, d in items]), entry.name,
                weight=np.stack([d.weight for _, d in items]),
                sigma=np.stack([d.sigma for _, d in items]) if has_sigma else None,
                fix=fix, init=init, metric=args.metric, cos_weight=args.cos_weight,
                max_zenith_deg=args.max_zenith_deg, max_steps=args.max_steps,
                guess=args.guess, progress=progress)
        finally:
            progress.close()
        rows += _batch_rows(paths, res, channels)
    _flag_rows(rows)
    if args.out is not None:
        _write_batch_table(rows, args.out)
    if args.json:
        print(json.dumps({"model": entry.name, "results": rows, "unreadable": bad}, indent=2))
    else:
        names = [n for n in entry.param_names]
        print(f"{entry.name} fitted to {len(rows)} file(s), metric {args.metric}")
        head = f"  {'file':<28} {'conv':>4} {'steps':>5} {'rms':>10}  " + "  ".join(names)
        print(head)
        for r in rows:
            vals = "  ".join(_fmt(r["params"][k]) for k in names)
            flag = "" if not r["at_bound"] else f"  (at bound: {', '.join(r['at_bound'])})"
            other = [f for f in r["flags"] if f not in ("not converged", "at bound")]
            if other:
                flag += f"  ({'; '.join(other)})"
            unid = [k for k, v in r["stderr_note"].items() if "not identifiable" in _note_text(v)]
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
        if args.out is not None:
            print(f"wrote {args.out}")
    return 0 if all(r["converged"] for r in rows) and not bad else 1


# ----------------------------------------------------------------------------- demo


def _short_params(params: dict) -> str:
    return ", ".join(f"{k}={_fmt(v)}" for k, v in params.items())


def _print_demo(doc: dict) -> None:
    ds = doc["dataset"]
    truth = doc["truth"]
    print(f"brdf-fit demo: {doc['summary']}\n")
    print(f"Synthetic gonioreflectometer data: {truth['model']} "
          f"({_short_params(truth['params'])}), {ds['plan']['name']} plan, {ds['n_samples']} "
          f"samples x {len(ds['channels'])} channels, 1% lognormal noise, seed "
          f"{doc['recipe']['seed']}")
    unit = " [sigma]" if doc["residual_units"] == "sigma" else ""
    at_once = doc.get("fit_workers", 1)
    print(f"\nModels ranked by residual rms ({doc['metric']} metric{unit}; ~1 = at the noise"
          + (f"; times with {at_once} fits at a time" if at_once > 1 else "") + "):")
    w = max(len(f["model"]) for f in doc["fits"])
    print(f"  {'#':>2} {'model':<{w}} {'rms':>10} {'conv':>5} {'steps':>5} {'time':>7}  "
          "parameters")
    for k, f in enumerate(doc["fits"], 1):
        print(f"  {k:>2} {f['model']:<{w}} {f['residual_rms']:10.4g} "
              f"{'yes' if f['converged'] else 'NO':>5} {f['steps']:>5} {f['seconds']:6.2f}s  "
              f"{_short_params(f['params'])}")
    und = [f for f in doc["fits"] if f.get("undetermined")]
    if und:
        from brdf_fit.fitting.problem import UNDETERMINED_RULE

        for f in und:
            parts = []
            for lab in f["undetermined"]:
                name, _, ch = lab.partition("[")
                j = doc["dataset"]["channels"].index(ch[:-1]) if ch else None
                v, se = f["params"][name], f["stderr"][name]
                v, se = (v, se) if j is None else (v[j], se[j])
                parts.append(f"{lab} = {v:.3g} +- {se:.2g}" if se is not None else lab)
            print(f"  {f['model']}: UNDETERMINED {', '.join(parts)}")
        print(f"  (flagged: {UNDETERMINED_RULE})")
    print("\nGGX width alpha: truth " + _fmt(truth["params"]["alpha"]) + "; fitted "
          + ", ".join(f"{k} {v:.4g}" for k, v in doc["ggx_alpha"].items()))
    for c in doc["conversions"]:
        kind = "Phong" if c["kind"] == "phong" else "Blinn-Phong"
        via = (f" -> Blinn-Phong n = {c['blinn_phong_exponent']:.4g}"
               if c["kind"] == "phong" else "")
        print(f"  {c['model']}: {kind} n = {c['exponent']:.4g}{via} -> GGX alpha = "
              f"{c['ggx_alpha']:.4g} (closed form, peak match: brdf_fit.convert.phong.{c['via']})")
    sel = doc.get("selection")
    if sel:
        committed = str(sel.get("cost_rule", "")).startswith("committed")
        refit = ("each model refitted in it" if "not refitted" not in sel["error_definition"]
                 else "of the fits above, not refitted")
        print("\nModel selection (brdf_fit.select; error: relative RMS of f cos(theta_i), "
              + refit + "; " + (
                  "the cheapest within budget by the committed cost, x Lambert from "
                  "brdf_fit/resources/catalogue_cost.json; ns/eval: this run's live timing):"
                  if committed else "cost measured in this run):"))
        for c in sel["candidates"]:
            if c["message"]:
                print(f"  {c['model']:<{w}} no fit: {c['message']}")
                continue
            mark = "  <- choice" if c["model"] == sel["choice"] else ""
            rel = ("" if c.get("cost_rel") is None
                   else f"{c['cost_rel']:5.2f} x Lambert  ")
            print(f"  {c['model']:<{w}} error {c['error']:8.4f}  {rel}{c['cost_ns']:7.2f} ns/eval  "
                  f"{'in' if c['within_budget'] else 'out'} budget{mark}")
        print(f"  budget {sel['budget']:.4g} ({sel['budget_rule']})")
    print(f"\nChecks on the best model ({doc['best']}):")
    for c in doc["checks"]:
        stat = "-" if c["statistic"] is None else f"{c['statistic']:.4g}"
        thr = "-" if c["threshold"] is None else f"{c['threshold']:.4g}"
        print(f"  {c['check']:<14} statistic {stat:>11}  threshold {thr:>11}  {c['status']}")
    print()
    if doc["plot_note"]:
        print(f"note: {doc['plot_note']}")
    for p in doc["plots"]:
        print(f"wrote {p}")
    print(f"wrote {doc['output']} ({doc['seconds']:.1f} s in all)")


def cmd_demo(args) -> int:
    """The main job on an embedded default (no input): synthesise -> fit -> rank -> convert ->
    check -> plots, written into ``--out``."""
    check_output_dir(args.out, "--out")
    from brdf_fit.demo import run_demo

    doc = run_demo(args.out, plots=not args.no_plots, progress=not args.quiet)
    if args.json:
        print(json.dumps(doc, indent=2))
    else:
        _print_demo(doc)
    return 0 if all(c["status"] != "FAIL" for c in doc["checks"]) else 1


CONVERSIONS = ("phong-to-ggx", "mtl-to-ggx")
#: the radiance error above which a conversion row does not represent its source (the same as
#: brdf_fit.convert.phong_to_ggx.REPRESENTS_TOL; tests/cli holds them equal)
REPRESENTS_TOL = 0.1


def _print_convert(doc: dict) -> None:
    print(f"{doc['source']} -> {doc['target']}: GGX alpha and f0 fitted to noise-free "
          f"{doc['source']} lobes (metric {doc['metric']})")
    print(f"geometry: {doc['geometry']}")
    print(f"closed form: {doc['closed_form']}")
    print(f"{'n':>8} {'n_blinn':>8} {'alpha_fit':>10} {'f0_fit':>7} {'alpha_cf':>9} {'ratio':>6} "
          f"{'rms':>8} {'rms_cf':>8} {'max_rel':>8} {'err/pk':>7} {'rad_err':>7} {'conv':>4} "
          f"{'N':>5}")
    for r in doc["rows"]:
        print(f"{r['exponent']:8.4g} {r['blinn_phong_exponent']:8.4g} {r['alpha_fit']:10.5g} "
              f"{r['f0_fit']:7.4f} {r['alpha_closed']:9.5g} {r['ratio']:6.3f} "
              f"{r['residual_rms']:8.4g} {r['closed_rms']:8.4g} {r['max_rel_err']:8.3g} "
              f"{r['max_err_over_peak']:7.3g} {r['radiance_error']:7.3g} "
              f"{'yes' if r['converged'] else 'NO':>4} "
              f"{r['n_samples']:5d}")
    print("rms: rms of the metric residual (rms_cf: GGX at alpha_cf and the peak-matched f0); "
          "max_rel: max |m-f|/f where f >= 10% of its maximum; err/pk: max |m-f| / max f; "
          "rad_err: relative RMS error of f cos(theta_i); ratio: alpha_fit/alpha_cf")
    bad = [r for r in doc["rows"] if not r["represents"]]
    if bad:
        ns = ", ".join(f"{r['exponent']:g}" for r in bad)
        print(f"warning: the fitted GGX does not represent {doc['source']} at n = {ns} "
              f"(radiance error above {REPRESENTS_TOL:g}); use it where the lobe shape matters "
              "little, or choose a model with brdf-fit select")


def cmd_convert(args) -> int:
    """Fit one model to data generated by another (:mod:`brdf_fit.convert.phong_to_ggx`)."""
    if args.conversion not in CONVERSIONS:
        raise CLIError(f"unknown conversion {args.conversion!r}; valid conversions: "
                       f"{', '.join(CONVERSIONS)}")
    if args.conversion == "mtl-to-ggx":
        return _convert_mtl(args)
    if args.file is not None:
        raise CLIError(f"{args.conversion} takes no FILE (mtl-to-ggx does)")
    _x64()
    from brdf_fit.convert.phong_to_ggx import phong_to_ggx

    bar, progress = _progress_callback(not args.quiet,
                                       lambda n: f"fitting GGX to {args.source} n = {n:g}")
    try:
        result = phong_to_ggx(args.source, exponents=args.exponents, metric=args.metric,
                              max_zenith_deg=args.max_zenith_deg, progress=progress)
    finally:
        bar.close()
    doc = result.to_dict()
    if args.json:
        print(json.dumps(doc, indent=2))
    else:
        _print_convert(doc)
    return _conversion_status((r["converged"], r["radiance_error"]) for r in doc["rows"])


def _convert_mtl(args) -> int:
    """``convert mtl-to-ggx FILE.mtl``: every material as GGX (:func:`brdf_fit.mtl_to_ggx`)."""
    if args.file is None:
        raise CLIError("mtl-to-ggx needs an MTL FILE: brdf-fit convert mtl-to-ggx scene.mtl")
    from brdf_fit.io.mtl import MtlError, read_mtl

    try:
        mats = read_mtl(args.file)
    except MtlError as exc:
        raise CLIError(str(exc)) from None
    _x64()
    from brdf_fit.convert.mtl import mtl_to_ggx

    bar, progress = _progress_callback(not args.quiet, lambda n: f"converting {n}")
    rows = []
    try:
        for i, m in enumerate(mats):
            progress(i, len(mats), m.name)
            rows.append(mtl_to_ggx(m, max_zenith_deg=args.max_zenith_deg))
        progress(len(mats), len(mats), "done")
    finally:
        bar.close()
    status = _conversion_status((r.converged, r.error) for r in rows)
    if args.json:
        print(json.dumps({"file": args.file, "materials": [r.to_dict() for r in rows]},
                         indent=2, allow_nan=False))
        return status
    w = max(len(r.name) for r in rows)
    print(f"{args.file}: {len(rows)} materials; error: relative RMS radiance error of the GGX "
          "material against the MTL material's meaning (brdf_fit.convert.mtl)")
    print(f"  {'material':<{w}} {'source':<22} {'target':<12} {'alpha':>7} {'rough':>6} "
          f"{'error':>7} {'closed a':>8} {'closed err':>10}")
    for r in rows:
        a = r.params.get("alpha")
        a_txt = "-" if a is None else f"{float(np.asarray(a)):.4g}"
        rg = "-" if r.roughness is None else f"{r.roughness:.3g}"
        ac = "-" if r.alpha_closed is None else f"{r.alpha_closed:.4g}"
        ec = "-" if r.error_closed is None else f"{r.error_closed:.3g}"
        print(f"  {r.name:<{w}} {r.source:<22} {r.target:<12} {a_txt:>7} {rg:>6} "
              f"{r.error:7.3g} {ac:>8} {ec:>10}")
        for n in r.notes:
            print(f"  {'':<{w}}   note: {n}")
    bad = [r.name for r in rows if not (r.converged and r.error <= REPRESENTS_TOL)]
    if bad:
        print(f"warning: {len(bad)} of {len(rows)} material(s) not represented by their GGX "
              f"conversion (radiance error above {REPRESENTS_TOL:g} or fit not converged): "
              f"{', '.join(bad)}; exit status 1")
    return status


def _conversion_status(results) -> int:
    """The exit status of every ``convert``, from ``(converged, radiance error)`` per
    conversion: 0 when each converged and represents its source (error <=
    :data:`REPRESENTS_TOL`), else 1 (the results are printed all the same): a script can trust
    a conversion that exits 0."""
    return 0 if all(c and e is not None and e <= REPRESENTS_TOL for c, e in results) else 1


def _progress_callback(enabled: bool, label):
    """A status bar and the ``progress(done, total, *extra)`` callback the library calls;
    ``label`` is the text, or a function of the callback's extra arguments (e.g. the model)."""
    bar = _Progress(0, enabled)

    def progress(done: int, total: int, *extra) -> None:
        if bar.enabled:
            bar.show(done, done, total, label(*extra) if callable(label) else label)

    return bar, progress


def cmd_plot(args) -> int:
    """Pictures of models (polar in-plane lobes + the hemisphere of the first model) or of data
    against models (in-plane slices + residuals), as PNG/PDF/SVG files."""
    import pathlib

    if not args.models and args.data is None:
        raise CLIError("plot needs a MODEL (e.g. 'brdf-fit plot ggx -o lobes.png') or --data FILE")
    if args.param and len(args.models) != 1:
        raise CLIError("--param needs exactly one MODEL")
    if args.fit and args.data is None:
        raise CLIError("--fit needs --data FILE")
    _check_angles("--theta-i-deg", args.theta_i_deg)
    if any(t >= 90.0 for t in args.theta_i_deg):
        raise CLIError("--theta-i-deg: incidence angles must be below 90 (the horizon)")
    check_output_file(args.output, (".png", ".pdf", ".svg"), "-o")
    out = pathlib.Path(args.output)
    second = out.with_name(f"{out.stem}_{'residuals' if args.data else 'hemisphere'}{out.suffix}")
    reg = _registry()
    entries = [reg.get(m) for m in args.models]  # unknown names fail before any work
    params = parse_params(args.param, entries[0]) if args.param else {}
    data = read_data(args.data) if args.data is not None else None
    if data is not None and not entries:
        raise CLIError("--data: name the MODEL(s) to draw against the data")
    _x64()
    from brdf_fit import plot

    models = []
    for e in entries:
        if args.fit:
            from brdf_fit.fitting.single import fit

            r = fit(data, e.name, fix=params or None)
            models.append((f"{e.name} (fit, rms {r.residual_rms:.3g})", r.model))
            print(f"{e.name}: fitted {', '.join(f'{k}={_fmt(v)}' for k, v in r.params.items())}"
                  f"{'' if r.converged else ' (NOT converged)'}")
        else:
            label = e.name + (f" ({_short_params(params)})" if params else "")
            models.append((label, e.build(**params)))
    if data is None:
        fig1 = plot.model_lobes(models, args.theta_i_deg, channel=args.channel)
        fig2 = plot.hemisphere(models[0][1], args.theta_i_deg, channel=args.channel,
                               title=models[0][0])
    else:
        fig1 = plot.in_plane_slices(data, models, args.theta_i_deg, channel=args.channel,
                                    title=args.data)
        fig2 = plot.residuals(data, models, title=args.data)
    fig1.savefig(out, dpi=110)
    fig2.savefig(second, dpi=110)
    print(f"wrote {out}")
    print(f"wrote {second}")
    return 0


def cmd_select(args) -> int:
    """Fit the candidates in the radiance error, measure their costs, choose the cheapest within
    the budget (:func:`brdf_fit.selection.select`)."""
    if args.budget is not None and not (math.isfinite(args.budget) and args.budget > 0):
        raise CLIError(f"--budget must be a positive number (0.02 = 2%), got {args.budget}")
    if args.plot is not None:
        check_output_file(args.plot, (".png", ".pdf", ".svg"), "--plot")
    if (args.scene is None) == (args.data is None):
        raise CLIError("select needs a DATA file or --scene TOML (one of them)")
    if args.scene is None:
        for flag, v in (("--max-models", args.max_models),
                        ("--skip-bad", args.skip_bad or None)):
            if v is not None:
                raise CLIError(f"{flag} needs --scene")
    if args.ceiling is not None and not args.ceiling > 0:
        raise CLIError(f"--ceiling must be a positive number (or inf), got {args.ceiling}")
    if args.target is not None:
        from brdf_fit.selection.selector import TARGETS

        if args.target not in TARGETS:
            raise CLIError(f"--target must be one of {', '.join(TARGETS)}, got "
                           f"{args.target!r}")
    if args.gltf is not None:
        check_output_file(args.gltf, (".gltf",), "--gltf")
    if args.mitsuba is not None:
        check_output_file(args.mitsuba, (".xml",), "--mitsuba")
    reg = _registry()
    names = None
    if args.candidates is not None and args.family is not None:
        raise CLIError("give --candidates or --family, not both")
    if args.family is not None:
        from brdf_fit.selection import family_candidates

        try:
            names = list(family_candidates(args.family))
        except ValueError as exc:
            raise CLIError(f"--family: {exc}") from None
    if args.candidates is not None:
        names = [c.strip() for c in args.candidates.split(",") if c.strip()]
        if not names:
            raise CLIError("--candidates: give at least one model name")
        names = [reg.get(n).name for n in names]  # unknown names fail before any work
    checks = _check_names(args.check) if args.check else ("reciprocity", "energy")
    if args.scene is not None:
        return _select_scene(args, names, checks)
    data = read_data(args.data)
    _x64()
    from brdf_fit.selection import select

    bar, progress = _progress_callback(not args.quiet, lambda name: f"fitting {name}")
    try:
        sel = select(data, names, args.budget, target=args.target,
                     checks=() if args.no_checks else checks, ceiling=args.ceiling,
                     anisotropy=not args.no_anisotropy, progress=progress)
    except ValueError as exc:
        raise CLIError(str(exc)) from None
    finally:
        bar.close()
    doc = sel.to_dict()
    doc["data"] = args.data
    if args.plot is not None:
        from brdf_fit.plot import selection_front

        selection_front(sel, title=args.data).savefig(args.plot, dpi=110)
        doc["plot"] = args.plot
    exports = []
    chosen = sel.choice
    if chosen is not None:
        name = os.path.splitext(os.path.basename(args.data))[0]
        for kind, path in (("mitsuba", args.mitsuba), ("gltf", args.gltf)):
            if path is not None:
                exports.append(_write_export(kind, path, chosen,
                                             sel.candidate(chosen).params, data, name))
    doc["exports"] = exports
    status = 0 if sel.choice is not None and sel.represented else 1
    if args.json:
        print(json.dumps(doc, indent=2, allow_nan=False))
        return status
    print(f"{args.data}: {data.n} samples x {data.n_channels} channels")
    print(f"error: {sel.error_definition}")
    print(f"budget: {sel.budget:.4g} ({sel.budget_rule})")
    if sel.noise_level is not None:
        print(f"noise level (from sigma): {sel.noise_level:.4g}")
    print(f"ceiling: {sel.ceiling:.4g} ({sel.ceiling_rule})")
    if sel.anisotropy is not None:
        a = sel.anisotropy
        stat = "-" if a.statistic is None else f"{a.statistic:.3f}"
        print(f"anisotropy: statistic {stat} (threshold {a.threshold:g}): {a.note}")
    if sel.target is not None:
        print(f"target: {sel.target} (every candidate is written to it as fitted)")
    print(f"cost: {sel.cost_rule}")
    _print_candidates(sel)
    print(sel.message if sel.choice is None else
          f"choice: {sel.choice} ({_short_params(sel.candidate(sel.choice).params)}), error "
          f"{sel.candidate(sel.choice).error:.4g}, {_cost_txt(sel.candidate(sel.choice))}")
    for ex in exports:
        err = ex["error"]
        print(f"export: {ex['target']} {ex['method']} "
              + ("(not verified)" if err is None else f"(round-trip error {err:.3g})")
              + f"; wrote {ex['path']}")
    if args.plot is not None:
        print(f"wrote {args.plot}")
    return status


def _cost_txt(c) -> str:
    rel = "" if c.cost_rel is None else f"{c.cost_rel:.2f}x Lambert (committed), "
    return f"{rel}{c.cost_ns:.3g} ns per evaluation (live)"


def _print_candidates(sel) -> None:
    w = max(len(c.model) for c in sel.candidates)
    print(f"  {'model':<{w}} {'error':>8} {'x lamb':>6} {'ns/eval':>8} {'k':>3} {'AIC':>10} "
          f"{'BIC':>10} {'chi2/dof':>9} {'conv':>5}  budget pareto checks")
    for c in sel.candidates:
        if c.message:
            print(f"  {c.model:<{w}} no fit: {c.message}")
            continue
        chi2 = "-" if c.reduced_chi2 is None else f"{c.reduced_chi2:.3g}"
        checks_txt = ",".join(f"{k}:{v}" for k, v in c.checks.items()) or "-"
        mark = "<- choice" if c.model == sel.choice else ""
        rel = "-" if c.cost_rel is None else f"{c.cost_rel:.2f}"
        print(f"  {c.model:<{w}} {c.error:8.4f} {rel:>6} {c.cost_ns:8.2f} {c.n_params:3d} "
              f"{c.aic:10.1f} {c.bic:10.1f} {chi2:>9} {'yes' if c.converged else 'no':>5}  "
              f"{'in' if c.within_budget else 'out':>6} {'*' if c.pareto else ' ':>6} "
              f"{checks_txt} {mark}")
    und = [f"{c.model}: {', '.join(c.undetermined)}" for c in sel.candidates if c.undetermined]
    if und:
        from brdf_fit.fitting.problem import UNDETERMINED_RULE

        print(f"  undetermined by the data ({UNDETERMINED_RULE}): " + "; ".join(und))


def _select_scene(args, names, checks) -> int:
    """``select --scene``: every material's choice, the model set, the exports."""
    if args.max_models is not None and args.max_models < 1:
        raise CLIError(f"--max-models must be an integer >= 1, got {args.max_models}")
    _x64()
    from brdf_fit.selection import scene as sc

    if args.scene == "example":
        args.scene = str(sc.EXAMPLE_SCENE)
    try:
        scene = sc.load_scene(args.scene, skip_bad=args.skip_bad)
    except sc.SceneError as exc:
        raise CLIError(str(exc)) from None
    bar, progress = _progress_callback(not args.quiet, lambda what: f"fitting {what}")
    try:
        res = sc.select_scene(scene, names, args.budget, family=None, target=args.target,
                              max_models=args.max_models, skip_bad=args.skip_bad,
                              checks=() if args.no_checks or not args.check else checks,
                              ceiling=args.ceiling, progress=progress)
    except (sc.SceneError, ValueError) as exc:
        raise CLIError(str(exc)) from None
    finally:
        bar.close()
    written = sc.export_scene(res, gltf_path=args.gltf, mitsuba_path=args.mitsuba)
    doc = res.to_dict()
    if args.plot is not None:
        from brdf_fit.plot import scene_front

        scene_front(res, title=res.scene.name).savefig(args.plot, dpi=110)
        written.append(args.plot)
    doc["written"] = written
    status = 0 if not res.scene.bad and not res.unrepresented() else 1
    if args.json:
        print(json.dumps(doc, indent=2, allow_nan=False))
        return status
    print(f"{args.scene}: {len(res.materials)} materials ({res.seconds:.1f} s)"
          + ("" if res.materials[0].selection.target is None else
             f", target {res.materials[0].selection.target}"))
    w = max(len(c.material.name) for c in res.materials)
    wm = max(len(c.model) for c in res.materials)
    print(f"  {'material':<{w}} {'kind':<5} {'model':<{wm}} {'error':>8} {'budget':>8} "
          f"{'ns/eval':>8}  exports")
    for c in res.materials:
        ex = ", ".join(
            f"{k} failed" if "method" not in v
            else f"{k} {v['method']} " + ("(not verified)" if v["error"] is None
                                          else f"{v['error']:.2g}")
            for k, v in c.exports.items()) or "-"
        print(f"  {c.material.name:<{w}} {c.material.kind:<5} {c.model:<{wm}} {c.error:8.4f} "
              f"{c.selection.budget:8.4f} {c.cost_ns:8.2f}  {ex}")
        for n in c.material.notes:
            print(f"  {'':<{w}}   note: {n}")
        a = c.selection.anisotropy
        if a is not None and a.present:
            print(f"  {'':<{w}}   {a.note}")
        if not c.selection.represented:
            print(f"  {'':<{w}}   {c.selection.message}")
        for k, v in c.exports.items():
            if "failed" in v:
                print(f"  {'':<{w}}   {k} export failed: {v['failed']}")
    print(f"model set ({res.set_rule}): {', '.join(res.model_set)}: {len(res.model_set)} "
          f"kernel(s), {res.cost_ns_total:.3g} ns per evaluation in all, worst error "
          f"{res.worst_error:.4g}")
    for b in res.scene.bad:
        print(f"skipped: {b['error']}")
    if res.unrepresented():
        print(f"not represented by any candidate: {', '.join(res.unrepresented())} (exit "
              "status 1)")
    for path in written:
        print(f"wrote {path}")
    return status


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
    entry = _registry().get(args.model)
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
    from brdf_fit.tables.export import write_table

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
    bar, progress = _progress_callback(not args.quiet, label)
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
    paths = write_table(table, args.output, half=args.half)
    seconds = time.perf_counter() - t0
    if args.plot is not None:
        from brdf_fit.plot import table_maps

        table_maps(table, title=f"{args.table} {entry.name}").savefig(args.plot, dpi=110)
        paths.append(args.plot)
    meta = table.meta
    doc = {"table": args.table, "model": entry.name, "params": meta["params"],
           "axes": [a.to_dict() for a in table.axes], "channels": list(table.channels),
           "error_estimate": meta.get("error_estimate"), "seconds": round(seconds, 3),
           "files": [str(p) for p in paths]}
    if args.json:
        print(json.dumps(doc, indent=2))
    else:
        err = (meta.get("error_estimate") or {}).get("max_abs")
        shape = " x ".join(f"{a.name}={a.n}" for a in table.axes)
        est = ("no error estimate is computed for this table" if err is None
               else f"error estimate {err:.2g} max abs")
        print(f"{args.table} of {entry.name} on {shape} ({','.join(table.channels)}): "
              f"{est}; {seconds:.2f} s")
        for p in paths:
            print(f"wrote {p}")
    return 0


def cmd_lut(args) -> int:
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
    from brdf_fit.tables.export import write_table
    from brdf_fit.tables.layouts import resolve_layout

    layout = resolve_layout(args.layout)
    if channels is not None:
        layout = dataclasses.replace(layout, channels=channels)
    bar, progress = _progress_callback(not args.quiet, f"dfg {args.size}x{args.size} texels")
    t0 = time.perf_counter()
    table = dfg_table(args.size, args.masking, layout=layout, progress=progress)
    bar.close()
    paths = write_table(table, args.output, half=args.half)
    seconds = time.perf_counter() - t0
    if args.plot is not None:
        from brdf_fit.plot import table_maps

        table_maps(table, title=f"DFG {args.size}x{args.size}, {table.meta['masking']}").savefig(
            args.plot, dpi=110)
        paths.append(args.plot)
    meta = table.meta
    doc = {"table": "dfg", "size": args.size, "layout": meta["layout"],
           "masking": meta["masking"], "channels": list(table.channels),
           "quadrature": meta["quadrature"],
           "error_estimate": {k: v for k, v in meta.get("error_estimate", {}).items()
                              if k in ("max_abs", "method")},
           "seconds": round(seconds, 3), "files": [str(p) for p in paths]}
    if args.json:
        print(json.dumps(doc, indent=2))
    else:
        err = doc["error_estimate"].get("max_abs")
        print(f"DFG {args.size}x{args.size} ({meta['masking']} masking, layout {args.layout}, "
              f"channels {','.join(table.channels)}): error estimate "
              f"{'-' if err is None else f'{err:.2g}'} max abs; {seconds:.2f} s")
        for p in paths:
            print(f"wrote {p}")
    return 0


def _fit_options(p, what: str, models: str = "registry name (see 'brdf-fit models')") -> None:
    """The options ``fit`` and ``fit-batch`` share (``what``: what the zenith cut does to a
    sample, "drop" or "mask"; ``models``: the help of ``--model``)."""
    p.add_argument("--model", required=True, help=models)
    p.add_argument("--fix", action="append", metavar="NAME=VALUE",
                   help="hold a parameter at a value (comma-separated for channels); repeatable")
    p.add_argument("--init", action="append", metavar="NAME=VALUE",
                   help="start value of a parameter (default: see --guess); repeatable")
    p.add_argument("--guess", default="grid", help="start of the parameters without --init: grid "
                                                    "(default: a coarse design on a subsample) "
                                                    "or none (the registry defaults)")
    p.add_argument("--metric", default="log",
                   help="log (default), cuberoot, relative, absolute, or the robust huber / "
                        "cauchy losses of the log residual (for outliers; not with sigma)")
    p.add_argument("--max-zenith-deg", type=float, default=None,
                   help=f"{what} samples with either direction beyond this zenith angle")
    p.add_argument("--cos-weight", action="store_true", help="weight residuals by cos(theta_i)")
    p.add_argument("--max-steps", type=_positive_int, default=256, metavar="N",
                   help="stop a fit after N solver steps (default 256; it is then reported as "
                        "not converged)")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="brdf-fit", description=__doc__.split("\n")[0])
    p.add_argument("--version", action="version", version=f"brdf-fit {__version__}")
    p.add_argument("--no-cache", action="store_true",
                   help="do not keep compiled programs between runs (default: kept in "
                        "$BRDF_FIT_CACHE_DIR or ~/.cache/brdf_fit/jax; BRDF_FIT_NO_CACHE=1 "
                        "also turns it off)")
    p.add_argument("--max-memory", type=_size, default=None, metavar="SIZE",
                   help="the most memory an input may make a command allocate, checked before "
                        "it is (e.g. 8G, 500M; default: half the machine's memory, or "
                        "$BRDF_FIT_MAX_MEMORY)")
    sub = p.add_subparsers(dest="command", required=True)

    m = sub.add_parser("models", help="list the registered models and their parameters")
    m.add_argument("--json", action="store_true", help="machine-readable output")
    m.set_defaults(func=cmd_models)

    k = sub.add_parser("catalogue", help="the Montes & Urena (2012) catalogue: which models are "
                                         "implemented, their checks, samplers and costs")
    k.add_argument("--json", action="store_true", help="machine-readable rows")
    k.add_argument("--write-readme", metavar="README", default=None,
                   help="rewrite the generated catalogue section of this file")
    k.set_defaults(func=cmd_catalogue)

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
    e.set_defaults(func=cmd_eval)

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
    c.set_defaults(func=cmd_check)

    y = sub.add_parser("synth", help="synthesise a dataset from a recipe (.json/.toml)")
    y.add_argument("recipe", help="recipe file (.json or .toml): model, params, seed, plan, "
                                  "noise; examples in examples/ (see data_synth.recipes)")
    y.add_argument("-o", "--output", required=True, metavar="FILE",
                   help="output data file: .csv or .npz (+ .json sidecar)")
    y.add_argument("--json", action="store_true", help="machine-readable summary")
    y.set_defaults(func=cmd_synth)

    f = sub.add_parser("fit", help="fit a registry model to measured data (or many files to "
                                   "several models: --table)")
    f.add_argument("data", nargs="+",
                   help="data file: .csv, .npz (or its .json sidecar), MERL .binary; with "
                        "--table any number of files and folders (a database run)")
    _fit_options(f, what="drop", models="registry name (see 'brdf-fit models'); with --table "
                                        "a comma-separated list")
    f.add_argument("--solver", default="lm",
                   help="lm (default), levenberg-marquardt, gauss-newton, gauss-newton-plain, "
                        "dogleg")
    f.add_argument("--multistart", type=_positive_int, default=1, metavar="K",
                   help="K starts (the first from --init, the others perturbed); best loss wins")
    f.add_argument("--seed", type=int, default=0, help="seed of multistart and --max-samples")
    f.add_argument("--max-samples", type=_positive_int, default=None, metavar="N",
                   help="fit a seeded random subset of N samples (e.g. of a MERL file)")
    f.add_argument("--time-limit", type=_positive_float, default=FIT_TIME_LIMIT, metavar="S",
                   help="stop a fit of large data (solved in chunks: a whole MERL file) that "
                        f"has not converged after S seconds, reported as not converged "
                        f"(default {FIT_TIME_LIMIT:g})")
    f.add_argument("--check", action="append", metavar="NAME",
                   help="run this check on the fitted model (repeatable)")
    f.add_argument("--target", default=None, metavar="T",
                   help="mitsuba or gltf: fit a model the target holds as fitted (a native "
                        "entry; a bare plugin name like roughplastic means mitsuba-roughplastic)")
    f.add_argument("--export", default=None, metavar="OUT",
                   help="write the fitted model for a renderer: .xml (Mitsuba 3 scene with one "
                        "bsdf) or .gltf (glTF 2.0 material), checked by round trip on the data")
    db = f.add_argument_group("a database run (many files x models, one table)")
    db.add_argument("--table", default=None, metavar="OUT.csv",
                    help="fit every file to every --model and write the table (CSV, and JSON "
                         "beside it: parameters, standard errors, rel. RMS and the published "
                         "error measures, time) and its figure (.png); each finished pair is "
                         "kept in OUT.csv.parts/, so the same command resumes a stopped run")
    db.add_argument("--processes", type=_positive_int, default=None, metavar="N",
                    help="share the pairs among N local processes")
    db.add_argument("--shard", default=None, metavar="I/N",
                    help="fit only pairs I, I+N, ... (one machine of several on a shared "
                         "folder; a run without --shard then writes the table)")
    f.add_argument("--json", action="store_true", help="print FitResult.to_dict() (a database "
                                                       "run: the table's JSON)")
    f.add_argument("--quiet", action="store_true", help="no status line on stderr")
    f.set_defaults(func=cmd_fit)

    fb = sub.add_parser("fit-batch", help="fit one registry model to many data files at once "
                                          "(brdf_fit.fit_batch)")
    fb.add_argument("data", nargs="*", help="data files (.csv, .npz, MERL .binary); files with "
                                            "equal sample counts are fitted in one batch")
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
    _fit_options(fb, what="mask")
    fb.add_argument("--skip-bad", action="store_true",
                    help="fit the readable files and list the unreadable ones (default: stop)")
    fb.add_argument("--out", default=None, metavar="FILE",
                    help="write one row per file to FILE (.csv or .json)")
    fb.add_argument("--json", action="store_true", help="print the per-file results as JSON")
    fb.add_argument("--quiet", action="store_true", help="no progress bar")
    fb.add_argument("--out-dir", default=None, metavar="DIR",
                    help="stream: read and fit the files block by block, writing each "
                         "finished block to DIR (block_*.npz, manifest.json); for many files")
    fb.add_argument("--block-size", type=_positive_int, default=None, metavar="N",
                    help="with --out-dir: files per block (default: from a 512 MB budget)")
    fb.add_argument("--resume", action="store_true",
                    help="with --out-dir: continue a killed run, fitting only the blocks not "
                         "written yet")
    mp = fb.add_argument_group("several processes (with --out-dir; JAX's multi-process "
                               "runtime, brdf_fit.fitting.distributed)")
    mp.add_argument("--processes", type=_positive_int, default=None, metavar="N",
                    help="start N local processes that share the blocks (one machine)")
    mp.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                    help="join a multi-process run whose process 0 listens at HOST:PORT "
                         "(with --num-processes and --process-id)")
    mp.add_argument("--num-processes", type=_positive_int, default=None, metavar="N")
    mp.add_argument("--process-id", type=int, default=None, metavar="I")
    mp.add_argument("--cluster", action="store_true",
                    help="join a multi-process run described by the cluster's environment "
                         "(SLURM, Open MPI: read by jax.distributed)")
    mp.add_argument("--join-timeout", type=float, default=None, metavar="S",
                    help="seconds to reach the coordinator before giving up (default 60)")
    fb.set_defaults(func=cmd_fit_batch)

    d = sub.add_parser("demo", help="the main job on an embedded default (no input needed)")
    d.add_argument("--out", default="brdf_fit_demo", metavar="DIR",
                   help="output folder for demo.json and plots (default: ./brdf_fit_demo)")
    d.add_argument("--json", action="store_true", help="print demo.json")
    d.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    d.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    d.set_defaults(func=cmd_demo)

    v = sub.add_parser("convert", help="fit one model to another's lobes (phong-to-ggx) and "
                                       "compare with the closed-form conversion")
    v.add_argument("conversion", help="phong-to-ggx, or mtl-to-ggx FILE.mtl (every material of "
                                      "a Wavefront MTL file fitted as GGX)")
    v.add_argument("file", nargs="?", default=None, help="the MTL file of mtl-to-ggx")
    v.add_argument("--source", default="modified-phong",
                   help="modified-phong (default, rho_d = 0), blinn-phong, blinn-phong-approx, "
                        "blinn-phong-microfacet (control: differs from GGX in D only)")
    v.add_argument("--exponents", type=float, nargs="+", default=[1.0, 10.0, 100.0, 1000.0],
                   metavar="N", help="source exponents (default: 1 10 100 1000)")
    v.add_argument("--metric", default="log", help="log (default), cuberoot, relative, absolute")
    v.add_argument("--max-zenith-deg", type=float, default=80.0,
                   help="largest zenith angle of either direction (default 80)")
    v.add_argument("--json", action="store_true",
                   help="machine-readable; its rows are a small fitted exponent -> alpha table "
                        "(brdf_fit.convert.phong_to_ggx.alpha_from_table)")
    v.add_argument("--quiet", action="store_true", help="no progress bar")
    v.set_defaults(func=cmd_convert)

    se = sub.add_parser("select", help="choose the cheapest model whose radiance error is "
                                       "within a budget")
    se.add_argument("data", nargs="?", default=None,
                    help="measured data (.csv, .npz, .binary); or --scene")
    se.add_argument("--scene", default=None, metavar="TOML",
                    help="a scene file: materials given as data files, MTL, glTF or registry "
                         "models (brdf_fit.selection.scene); prints the choice per material and "
                         "the model set; 'example' is the embedded example scene")
    se.add_argument("--max-models", type=int, default=None, metavar="K",
                    help="with --scene: at most K models for the whole scene (the set that "
                         "minimises the worst error)")
    se.add_argument("--gltf", default=None, metavar="OUT.gltf",
                    help="write the chosen material(s) as glTF 2.0 materials")
    se.add_argument("--mitsuba", default=None, metavar="OUT.xml",
                    help="write the chosen material(s) as Mitsuba 3 bsdfs")
    se.add_argument("--skip-bad", action="store_true",
                    help="with --scene: list bad materials and select the others")
    se.add_argument("--candidates", default=None, metavar="A,B,...",
                    help="registry names (default: lambert, oren-nayar, modified-phong, "
                         "blinn-phong, ward, beckmann, ggx, ggx-plastic, ggx-conductor, "
                         "cook-torrance)")
    se.add_argument("--family", default=None, metavar="NAME",
                    help="a named candidate set instead: diffuse, phong, microfacet, plastic, "
                         "conductor, anisotropic, default, or all (every fittable entry)")
    se.add_argument("--budget", type=float, default=None,
                    help="largest relative RMS radiance error (0.02 = 2%%; default: twice the "
                         "best candidate's error, at least 1.5x the noise level with sigma, "
                         "at least 0.01)")
    se.add_argument("--target", default=None, metavar="T",
                    help="mitsuba or gltf: select among the models the target holds as fitted "
                         "(its native entries), so the export is the fit itself")
    se.add_argument("--ceiling", type=float, default=None, metavar="E",
                    help="error above which no candidate represents the material (default: "
                         "0.05 above the noise level; inf turns it off); then the exit "
                         "status is 1")
    se.add_argument("--no-anisotropy", action="store_true",
                    help="skip the anisotropy test (it adds anisotropic candidates when the "
                         "data need two widths)")
    se.add_argument("--check", action="append", metavar="NAME",
                    help="checks run on each fitted candidate (default: reciprocity, energy)")
    se.add_argument("--no-checks", action="store_true", help="run no checks")
    se.add_argument("--plot", default=None, metavar="PNG",
                    help="error against cost, the budget line and the choice")
    se.add_argument("--json", action="store_true", help="machine-readable result")
    se.add_argument("--quiet", action="store_true", help="no progress bar")
    se.set_defaults(func=cmd_select)

    pl = sub.add_parser("plot", help="draw models (polar lobes, hemisphere) or data against "
                                     "models (in-plane slices, residuals)")
    pl.add_argument("models", nargs="*", metavar="MODEL", help="registry model name(s)")
    pl.add_argument("-o", "--output", required=True,
                    help="picture (.png, .pdf, .svg); a second one is written beside it "
                         "(NAME_hemisphere or NAME_residuals)")
    pl.add_argument("--param", action="append", metavar="NAME=VALUE",
                    help="a parameter of the (single) MODEL; repeatable")
    pl.add_argument("--data", default=None, metavar="FILE",
                    help="measured data (.csv, .npz, .binary) to draw against the models")
    pl.add_argument("--fit", action="store_true", help="fit each MODEL to --data first")
    pl.add_argument("--theta-i-deg", type=float, nargs="+", default=[0.0, 30.0, 60.0],
                    metavar="DEG", help="incidence angles, one panel each (default 0 30 60)")
    pl.add_argument("--channel", type=int, default=None,
                    help="channel index to draw (default: G of RGB, else the first)")
    pl.set_defaults(func=cmd_plot)

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
    t.add_argument("--size", type=_positive_int, default=128, metavar="N",
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
    t.set_defaults(func=cmd_lut)
    return p


def _user_errors() -> tuple[type[BaseException], ...]:
    """Exception classes that mean a user error (one line, exit 2). Looked up among the modules
    already imported, so the CLI imports nothing for them: an exception of a module that was
    never imported cannot have been raised."""
    errors: list[type[BaseException]] = [CLIError]
    for module, names in (("brdf_fit.core.validate", ("ParameterError",)),
                          ("brdf_fit.core.limits", ("LimitError",)),
                          ("brdf_fit.core.runlock", ("FolderBusy",)),
                          ("brdf_fit.fitting.problem", ("FitError",)),
                          ("brdf_fit.data", ("DataError",)),
                          ("data_synth.recipes", ("RecipeError",)),
                          ("data_synth.plans", ("PlanError",)),
                          ("data_synth.noise", ("NoiseError",)),
                          ("brdf_fit.convert.phong_to_ggx", ("ConversionError",))):
        mod = sys.modules.get(module)
        errors.extend(getattr(mod, n) for n in names if mod is not None and hasattr(mod, n))
    return tuple(errors)


#: where compiled XLA programs are kept between runs (JAX's persistent compilation cache)
CACHE_ENV = "BRDF_FIT_CACHE_DIR"
NO_CACHE_ENV = "BRDF_FIT_NO_CACHE"
#: the folder of exported solver programs (brdf_fit.fitting._export.ENV)
EXPORT_ENV = "BRDF_FIT_EXPORT_DIR"


def cache_dir() -> str | None:
    """The persistent compilation cache folder: ``$BRDF_FIT_CACHE_DIR``, else
    ``$XDG_CACHE_HOME/brdf_fit/jax`` (``~/.cache/brdf_fit/jax``); None when
    ``$BRDF_FIT_NO_CACHE`` is set (to anything but 0 or an empty string)."""
    import os

    if os.environ.get(NO_CACHE_ENV, "") not in ("", "0"):
        return None
    if os.environ.get(CACHE_ENV):
        return os.environ[CACHE_ENV]
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "brdf_fit", "jax")


def _enable_compilation_cache(enabled: bool) -> None:
    """Turn on JAX's persistent compilation cache for this process, through the environment
    JAX reads when it is first imported (so ``--help`` and argument errors still import no JAX).
    Every program is cached (minimum compile time 0): the CLI's compiles are many and short,
    and a second run of the same command with the same shapes then compiles nothing. Without
    effect when JAX is already imported (the tests call ``main`` in-process). Also names the
    folder of exported (traced and lowered) solver programs, ``<cache>/exported``
    (``$BRDF_FIT_EXPORT_DIR``, :mod:`brdf_fit.fitting._export`), so that a warm ``fit`` does
    not trace the model either; ``--no-cache`` unsets it."""
    import os

    path = cache_dir() if enabled else None
    if path is None:
        os.environ.pop(EXPORT_ENV, None)  # --no-cache: no exported programs either
        return
    try:
        os.makedirs(path, exist_ok=True)
    except OSError:
        return  # an unwritable cache is no error: the command runs without it
    # traced and lowered solver programs (brdf_fit.fitting._export), next to XLA's compiled ones
    os.environ.setdefault(EXPORT_ENV, os.path.join(path, "exported"))
    if "jax" in sys.modules:
        return
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", path)
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """Warnings the library raises for the user (a clamped parameter, ...) as one line."""
    print(f"brdf-fit: warning: {' '.join(str(message).split())}", file=file or sys.stderr)


class _Terminated(BaseException):
    """SIGTERM, raised in the main thread (as KeyboardInterrupt is for SIGINT) so that a
    command stops the same way: what is finished kept, one line, exit status 143."""


def _raise_terminated(signum, frame):
    raise _Terminated()


def _interrupted(args, status: int) -> int:
    """One line for an interrupted command (130: SIGINT, 143: SIGTERM), saying how to go on
    where the command keeps its work in a folder; the JSON answer under --json."""
    what = "interrupted" if status == 130 else "terminated"
    out_dir = getattr(args, "out_dir", None)
    msg = (f"{what}; the blocks written are kept in {out_dir}: the same command with --resume "
           "continues" if out_dir else what)
    print(f"brdf-fit: {msg}", file=sys.stderr)
    if getattr(args, "json", False):
        print(json.dumps({"error": msg, "exit_status": status}))
    return status


def main(argv: list[str] | None = None) -> int:
    import signal
    import warnings

    args = build_parser().parse_args(argv)
    args._argv = None if argv is None else list(argv)
    if args.max_memory is not None:  # read by brdf_fit.core.limits; children inherit it
        os.environ["BRDF_FIT_MAX_MEMORY"] = str(args.max_memory)
    _enable_compilation_cache(not args.no_cache)
    shown = warnings.showwarning
    warnings.showwarning = _show_warning
    try:
        previous = signal.signal(signal.SIGTERM, _raise_terminated)
    except ValueError:  # not the main thread: leave signals to whoever owns it
        previous = None
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return _interrupted(args, 130)
    except _Terminated:
        return _interrupted(args, 143)
    except KeyError as exc:  # unknown model (registry.UnknownModelError)
        print(f"brdf-fit: error: {exc}", file=sys.stderr)
        if getattr(args, "json", False):
            print(json.dumps({"error": str(exc).strip("'\""), "exit_status": 2}))
        return 2
    except BrokenPipeError:  # output piped into `head` and closed early: not an error
        sys.stderr.close()
        return 0
    except Exception as exc:
        if isinstance(exc, _user_errors()):
            msg = " ".join(str(exc).split("\n"))
            print(f"brdf-fit: error: {msg}", file=sys.stderr)
            if getattr(args, "json", False):  # a script that parses stdout gets an answer too
                print(json.dumps({"error": msg, "exit_status": 2}))
            return 2
        raise
    finally:
        warnings.showwarning = shown
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
