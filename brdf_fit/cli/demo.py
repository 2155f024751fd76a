"""``brdf-fit demo``: the main job on an embedded default."""

from __future__ import annotations

import sys

from brdf_fit.cli._common import (
    check_output_dir,
    fmt,
    short_params,
    strict_json,
)


def _print_demo(doc: dict) -> None:
    ds = doc["dataset"]
    truth = doc["truth"]
    print(f"brdf-fit demo: {doc['summary']}\n")
    print(f"Synthetic gonioreflectometer data: {truth['model']} "
          f"({short_params(truth['params'])}), {ds['plan']['name']} plan, {ds['n_samples']} "
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
              f"{short_params(f['params'])}")
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
    print("\nGGX width alpha: truth " + fmt(truth["params"]["alpha"]) + "; fitted "
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
    done = "NOT written" if doc["output"] in doc.get("error", "") else "wrote"
    print(f"{done} {doc['output']} ({doc['seconds']:.1f} s in all)")


def run(args) -> int:
    """The main job on an embedded default (no input): synthesise -> fit -> rank -> convert ->
    check -> plots, written into ``--out``."""
    check_output_dir(args.out, "--out")
    from brdf_fit.demo import run_demo

    doc = run_demo(args.out, plots=not args.no_plots, progress=not args.quiet)
    failed = doc.pop("write_error", None)
    if failed is not None:  # the results are printed all the same: nothing computed is lost
        doc.update(error=f"--out {failed}; the result is printed instead", exit_status=1)
    if args.json:
        print(strict_json(doc))
    else:
        _print_demo(doc)
    status = 0 if all(c["status"] != "FAIL" for c in doc["checks"]) else 1
    if failed is not None:
        print(f"brdf-fit: error: {doc['error']}", file=sys.stderr)
        return max(status, 1)
    return status


def add_parser(sub) -> None:
    d = sub.add_parser("demo", help="the main job on an embedded default (no input needed)")
    d.add_argument("--out", default="brdf_fit_demo", metavar="DIR",
                   help="output folder for demo.json and plots (default: ./brdf_fit_demo)")
    d.add_argument("--json", action="store_true", help="print demo.json")
    d.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    d.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    d.set_defaults(func=run)
