"""The main job on an embedded default: synthesise rough gold on a four-axis gonioreflectometer
plan, fit several models (flagging the parameters the data do not determine), rank them, convert
the fitted Phong exponent to a GGX width, choose the cheapest model within budget from those
fits, check the best model, and write ``demo.json`` (and plots) into a folder. ``brdf-fit demo``
prints it.

Cold (empty caches) it is compilation-bound; the fits run two at a time in threads, the
selection judges the fits as they are rather than refitting each (which doubled the
compilations), evaluation is compiled whole (:func:`brdf_fit.models._base.evaluate`), and the
plots are drawn while the checks run. Measured on an idle 2-core AMD EPYC: 64 s cold before
these changes; 14.9-17.5 s cold in ten runs (median 15.7 s, 2026-12-05; 15.6-23.7 s the day
before with other work on the machine), 6.4 s warm (``time brdf-fit demo`` with an empty cache
folder, and ``benchmarks/bench_latency.py``: results/latency_amd_epyc.md).

This is the application layer: it uses the synthetic instrument (:mod:`data_synth`) and the
library; nothing in the library imports it.
"""

from __future__ import annotations

import io
import json
import pathlib
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import jax
import numpy as np

from brdf_fit import plot, registry
from brdf_fit.convert import phong as cp
from brdf_fit.core.atomic import write_bytes_atomic, write_text_atomic
from brdf_fit.fitting.problem import UNDETERMINED_RULE
from brdf_fit.fitting.single import fit
from brdf_fit.selection import select
from brdf_fit.verify.checks import run_checks
from data_synth.recipes import synthesize

__all__ = ["DEMO_SUMMARY", "DEMO_RECIPE", "DEMO_FITS", "DEMO_METRIC", "DEMO_CHECKS", "run_demo"]


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
    ("modified-phong", {}),
)
#: what the demo shows, in one line (printed first)
DEMO_SUMMARY = ("rough gold on a virtual gonioreflectometer: fit three models, flag what the "
                "data cannot determine, convert the Phong exponent to a GGX width, choose the "
                "cheapest model within budget, check the best")
DEMO_METRIC = "log"
DEMO_CHECKS = ("non-negative", "reciprocity", "energy")
DEMO_SLICES_DEG = (0.0, 30.0, 60.0)
#: fits run at once (threads; the demo is meant for 2 cores)
DEMO_WORKERS = 2


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


def _render(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return buf.getvalue()


def _fit_plots(data, ranked) -> dict[str, bytes]:
    """The PNG files of the fits (slices and residuals), rendered in memory: the demo draws
    them while its selection and checks run, and writes them after ``demo.json``."""
    models = [(r.model_name, r.model) for r in ranked]
    truth = ", ".join(f"{k}={v}" for k, v in DEMO_RECIPE["params"].items())
    return {
        "demo_slices.png": _render(plot.in_plane_slices(
            data, models, DEMO_SLICES_DEG,
            title=f"{DEMO_RECIPE['model']} ({truth}), 1% noise, and the models fitted to it "
                  "(log chi-square)")),
        "demo_residuals.png": _render(plot.residuals(
            data, models, title=f"log residuals per model (metric {DEMO_METRIC}); dashed: "
                                "+-1 median sigma")),
    }


def _selection_plot(selection) -> dict[str, bytes]:
    return {"demo_selection.png": _render(plot.selection_front(
        selection, title="model selection: radiance error against measured cost"))}


def run_demo(out_dir, plots: bool = True, progress: bool = True) -> dict:
    """The main job: synthesise, fit every model of :data:`DEMO_FITS`, rank, convert, check, write
    ``demo.json`` (and plots) into ``out_dir``. Returns the JSON document; a file that could not
    be written is named in its ``write_error`` (the document is complete all the same)."""
    # fitting runs in float64 (see brdf_fit.cli._common.use_x64)
    jax.config.update("jax_enable_x64", True)
    t0 = time.perf_counter()

    def note(msg):
        if progress:
            print(f"[demo {time.perf_counter() - t0:5.1f} s] {msg}", file=sys.stderr, flush=True)

    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    note(DEMO_SUMMARY)
    data = synthesize(DEMO_RECIPE)
    note(f"synthesised {data.n} samples x {data.n_channels} channels "
         f"({DEMO_RECIPE['plan']['name']} plan, seed {DEMO_RECIPE['seed']})")
    results = {}
    # the fits run DEMO_WORKERS at a time, in threads: XLA compiles with the interpreter lock
    # released, so one fit's compilation overlaps another's tracing (the results are the same
    # as one at a time, to the last bit; the compilations are most of a cold demo)
    done = iter(range(1, len(DEMO_FITS) + 1))

    def one(item):
        name, init = item
        r = fit(data, name, init=init, metric=DEMO_METRIC)
        note(f"fit {next(done)}/{len(DEMO_FITS)} {name}: rms {r.residual_rms:.4g}, {r.steps} "
             f"steps, {'converged' if r.converged else 'NOT converged'}, {r.seconds:.1f} s")
        return r

    with ThreadPoolExecutor(DEMO_WORKERS) as pool:
        for (name, _), r in zip(DEMO_FITS, pool.map(one, DEMO_FITS), strict=True):
            results[name] = r
    ranked = sorted(results.values(), key=lambda r: r.residual_rms)
    best = ranked[0]
    # which model renders this material within budget at the least cost (brdf_fit.select on
    # the fits above, each judged in the relative radiance error as fitted, not refitted in it:
    # a second fit per model would double the demo's compilations; the committed cost table
    # decides, so the choice does not move with this run's timings; nothing else runs while
    # its live ns/eval are timed)
    sel = select(data, fits=results, checks=())
    note(f"selection: {sel.choice} (budget {sel.budget:.3g}, {sel.budget_rule})")
    # the plots are drawn (in memory) by a second thread while the checks run here: both are
    # mostly outside the interpreter lock (rendering, XLA)
    pics: dict = {}
    plot_error: list = []

    def draw():
        try:
            pics.update(_fit_plots(data, ranked))
            pics.update(_selection_plot(sel))
        except Exception as e:  # a failing plot never loses the computed results
            plot_error.append(e)

    drawer = threading.Thread(target=draw, daemon=True) if plots else None
    if drawer is not None:
        drawer.start()
    checks = run_checks(best.model, checks=list(DEMO_CHECKS), name=best.model_name,
                        expected_failures=registry.get(best.model_name).expected_failures)
    note(f"checks on {best.model_name}: "
         + ", ".join(f"{c.check} {c.status}" for c in checks))
    best.checks = checks
    doc = {
        "summary": DEMO_SUMMARY,
        "recipe": DEMO_RECIPE,
        "dataset": {"n_samples": data.n, "channels": list(data.channels),
                    "plan": data.metadata["plan"], "noise": data.metadata["noise"]},
        "truth": {"model": DEMO_RECIPE["model"],
                  "params": {k: np.asarray(v).tolist()
                             for k, v in registry.get(DEMO_RECIPE["model"]).defaults().items()
                             } | DEMO_RECIPE["params"]},
        "metric": DEMO_METRIC,
        "fit_workers": DEMO_WORKERS,
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

    def write() -> bool:
        """demo.json, whole or not at all; a failure is kept in the document (``write_error``),
        which the caller still has: nothing computed is lost to a full disk."""
        doc["seconds"] = round(time.perf_counter() - t0, 2)
        try:
            write_text_atomic(path, json.dumps(doc, indent=2) + "\n")
        except OSError as e:
            doc["write_error"] = f"{path}: cannot write ({e.strerror or e})"
            return False
        return True

    wrote = write()  # the results are on disk before any plot file is written
    if drawer is not None:
        drawer.join()
        files = []
        for name, png in pics.items():
            if not wrote:
                break
            try:
                write_bytes_atomic(out_dir / name, png)
            except OSError as e:
                doc["write_error"] = f"{out_dir / name}: cannot write ({e.strerror or e})"
                break
            files.append(str(out_dir / name))
        doc["plots"] = files
        if plot_error:
            e = plot_error[0]
            doc["plot_note"] = (f"plots failed ({type(e).__name__}: {e}); demo.json is "
                                "complete")
        if doc["plots"]:
            note(f"plots: {', '.join(doc['plots'])}")
        if wrote:
            write()
    return doc
