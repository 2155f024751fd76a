"""The main job on an embedded default: synthesise rough gold on a four-axis gonioreflectometer
plan, fit several models, rank them, convert the fitted Phong exponents to a GGX width, check the
best model, and write ``demo.json`` (and plots) into a folder. ``brdf-fit demo`` prints it.

This is the application layer: it uses the synthetic instrument (:mod:`data_synth`) and the
library; nothing in the library imports it.
"""

from __future__ import annotations

import json
import pathlib
import sys
import time

import jax
import numpy as np

from brdf_fit import plot, registry
from brdf_fit.convert import phong as cp
from brdf_fit.fitting.problem import UNDETERMINED_RULE
from brdf_fit.fitting.single import fit
from brdf_fit.selection import select
from brdf_fit.verify.checks import run_checks
from data_synth.recipes import synthesize

__all__ = ["DEMO_RECIPE", "DEMO_FITS", "DEMO_METRIC", "DEMO_CHECKS", "run_demo"]


#: The demo's dataset: gold (GGX, exact conductor Fresnel, the registry's gold eta/k) at
#: alpha = 0.2, scanned by a four-axis gonioreflectometer with 1% lognormal noise.
DEMO_RECIPE = {
    "name": "demo-gold-ggx",
    "description": "rough gold (GGX, alpha 0.2) on a four-axis gonioreflectometer, 1% noise",
    "model": "ggx-conductor",
    "params": {"alpha": 0.2},
    "seed": 2024,
    "plan": {"name": "four_axis",
             "args": {"theta_i_deg": [0.0, 15.0, 30.0, 45.0, 60.0, 75.0],
                      "theta_o_deg": [0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0],
                      "phi_o_deg": [float(p) for p in range(0, 360, 30)],
                      "max_zenith_deg": 80.0, "min_separation_deg": 5.0}},
    "noise": [{"type": "lognormal", "args": {"sigma": 0.01}}],
}
#: The models the demo fits, with their start values. ggx-conductor starts from a neutral metal
#: (not from the truth, the registry's gold default), so the fit has something to find.
DEMO_FITS = (
    ("ggx-conductor", {"alpha": 0.4, "eta": [1.0, 1.0, 1.0], "k": [3.0, 3.0, 3.0]}),
    ("ggx", {}),
    ("beckmann", {}),
    ("modified-phong", {}),
    ("blinn-phong-approx", {}),
)
DEMO_METRIC = "log"
DEMO_CHECKS = ("non-negative", "reciprocity", "energy")
DEMO_SLICES_DEG = (0.0, 30.0, 60.0)


def _demo_conversions(results: dict) -> list[dict]:
    """Closed-form Phong / Blinn-Phong exponent -> GGX alpha (peak match) of the fitted lobes."""
    out = []
    if "modified-phong" in results:
        n = float(np.asarray(results["modified-phong"].params["exponent"]))
        nb = float(cp.phong_to_blinn_phong_exponent(n))
        out.append({"model": "modified-phong", "exponent": n, "kind": "phong",
                    "blinn_phong_exponent": nb,
                    "ggx_alpha": float(cp.blinn_phong_to_ggx_alpha(nb)),
                    "via": "phong_to_blinn_phong_exponent, blinn_phong_to_ggx_alpha"})
    if "blinn-phong-approx" in results:
        n = float(np.asarray(results["blinn-phong-approx"].params["exponent"]))
        out.append({"model": "blinn-phong-approx", "exponent": n, "kind": "blinn-phong",
                    "blinn_phong_exponent": n,
                    "ggx_alpha": float(cp.blinn_phong_to_ggx_alpha(n)),
                    "via": "blinn_phong_to_ggx_alpha"})
    return out


def _demo_plots(data, ranked, out_dir, selection=None) -> tuple[list[str], str | None]:
    models = [(r.model_name, r.model) for r in ranked]
    files = []
    truth = ", ".join(f"{k}={v}" for k, v in DEMO_RECIPE["params"].items())
    # next to each model's chi-square fit (solid), its best approximation in the selection's
    # radiance error (dashed; none where that fit failed)
    paired = None
    if selection is not None:
        by_name = {c.model: c for c in selection.candidates}
        paired = [(f"{n} (radiance fit)", by_name[n].fitted)
                  if n in by_name and by_name[n].fitted is not None else None
                  for n, _ in models]
    figs = {
        "demo_slices.png": plot.in_plane_slices(
            data, models, DEMO_SLICES_DEG, paired=paired,
            title=f"{DEMO_RECIPE['model']} ({truth}), 1% noise: solid, fitted in the log "
                  "chi-square; dashed, in the radiance error"),
        "demo_residuals.png": plot.residuals(
            data, models, title=f"log residuals per model (metric {DEMO_METRIC}); dashed: "
                                "+-1 median sigma"),
    }
    if selection is not None:
        figs["demo_selection.png"] = plot.selection_front(
            selection, title="model selection: radiance error against measured cost")
    for name, fig in figs.items():
        path = out_dir / name
        fig.savefig(path, dpi=110)
        files.append(str(path))
    return files, None


def run_demo(out_dir, plots: bool = True, progress: bool = True) -> dict:
    """The main job: synthesise, fit every model of :data:`DEMO_FITS`, rank, convert, check, write
    ``demo.json`` (and plots) into ``out_dir``. Returns the JSON document."""
    jax.config.update("jax_enable_x64", True)  # fitting runs in float64 (see brdf_fit.cli._x64)
    t0 = time.perf_counter()

    def note(msg):
        if progress:
            print(f"[demo {time.perf_counter() - t0:5.1f} s] {msg}", file=sys.stderr, flush=True)

    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    data = synthesize(DEMO_RECIPE)
    note(f"synthesised {data.n} samples x {data.n_channels} channels "
         f"({DEMO_RECIPE['plan']['name']} plan, seed {DEMO_RECIPE['seed']})")
    results = {}
    for k, (name, init) in enumerate(DEMO_FITS, 1):
        r = fit(data, name, init=init, metric=DEMO_METRIC)
        results[name] = r
        note(f"fit {k}/{len(DEMO_FITS)} {name}: rms {r.residual_rms:.4g}, {r.steps} steps, "
             f"{'converged' if r.converged else 'NOT converged'}, {r.seconds:.1f} s")
    ranked = sorted(results.values(), key=lambda r: r.residual_rms)
    best = ranked[0]
    # which model renders this material within budget at the least cost (brdf_fit.select:
    # each candidate refitted in the relative radiance error; the committed cost table decides,
    # so the choice does not move with this run's timings)
    def sel_progress(done, total, what):  # the longest step: say what it is doing
        if what and what != "done":
            note(f"selection: {what}" if what == "anisotropy test"
                 else f"selection {done + 1}/{total}: refitting {what} in the radiance error")

    sel = select(data, [name for name, _ in DEMO_FITS], checks=(), progress=sel_progress)
    note(f"selection: {sel.choice} (budget {sel.budget:.3g}, {sel.budget_rule})")
    checks = run_checks(best.model, checks=list(DEMO_CHECKS), name=best.model_name,
                        expected_failures=registry.get(best.model_name).expected_failures)
    best.checks = checks
    note(f"checks on {best.model_name}: "
         + ", ".join(f"{c.check} {c.status}" for c in checks))
    doc = {
        "recipe": DEMO_RECIPE,
        "dataset": {"n_samples": data.n, "channels": list(data.channels),
                    "plan": data.metadata["plan"], "noise": data.metadata["noise"]},
        "truth": {"model": DEMO_RECIPE["model"],
                  "params": {k: np.asarray(v).tolist()
                             for k, v in registry.get(DEMO_RECIPE["model"]).defaults().items()
                             } | DEMO_RECIPE["params"]},
        "metric": DEMO_METRIC,
        "residual_units": "sigma" if data.sigma is not None else "metric",
        "ranking": [r.model_name for r in ranked],
        "best": best.model_name,
        "fits": [r.to_dict() for r in ranked],
        "undetermined_rule": UNDETERMINED_RULE,
        "conversions": _demo_conversions(results),
        "ggx_alpha": {n: float(np.asarray(results[n].params["alpha"]))
                      for n in ("ggx-conductor", "ggx", "beckmann") if n in results},
        "checks": [c.to_dict() for c in checks],
        "selection": sel.to_dict(),
        "plots": [],
        "plot_note": "plots disabled" if not plots else None,
        "seconds": 0.0,
    }
    path = out_dir / "demo.json"
    doc["output"] = str(path)

    def write():
        doc["seconds"] = round(time.perf_counter() - t0, 2)
        path.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")

    write()  # the results are on disk before any plot is attempted
    if plots:
        try:
            doc["plots"], doc["plot_note"] = _demo_plots(data, ranked, out_dir, sel)
        except Exception as e:  # a failing plot never loses the computed results
            doc["plot_note"] = f"plots failed ({type(e).__name__}: {e}); demo.json is complete"
        if doc["plots"]:
            note(f"plots: {', '.join(doc['plots'])}")
        write()
    return doc
