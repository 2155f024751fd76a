"""One speed-against-error report of brdf_fit, every figure measured in the same run.

    python benchmarks/report.py [--quick] [--out benchmarks/results]

Writes ``<out>/REPORT.md`` and its plots ``<out>/report/*.png``:

1. per registry model (non-delta, registry defaults): ``jit(eval)`` cost in float32 on N direction
   pairs (median of interleaved samples, ratio to ``lambert`` in the same run) against the float32
   relative error versus float64 at the same directions (the headline plot);
2. Fresnel variants on a GGX conductor (Schlick, exact dielectric, exact conductor RGB,
   spectral conductor integrated to RGB) for Au, Cu, Ag, Al: cost per BRDF evaluation (ratio to
   Schlick) against the CIEDE2000 colour difference of a white-lit sphere, the spectral variant as
   reference;
3. half-vector quadrature order against the GGX directional albedo error (SciPy adaptive
   reference of ``bench_albedo_quadrature.py``);
4. DFG table size against interpolation error (linear and cubic ``Table.lookup`` at random
   off-grid points, reference: direct quadrature) and memory;
5. fitting time against parameter error: a ``fit`` loop, ``fit_batch``, a SciPy
   ``least_squares`` loop on the same synthetic GGX problems (``bench_fit_batch.py``'s
   problems and SciPy loop);
6. the catalogue cost table (read from ``brdf_fit/resources/catalogue_cost.json``, written by
   ``bench_catalogue_cost.py``; not re-measured), next to item 1's float32 ratio.

float64 is enabled (the references need it); every float32 measurement casts its parameters and
directions to float32 explicitly and checks that the output is float32. ``--quick``: small sizes
(a smoke run of ~1-2 minutes; its numbers are not meant for the committed report).
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
import tempfile
import time
import warnings
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import colour  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import matplotlib  # noqa: E402
import matplotlib.patches  # noqa: E402
import matplotlib.text  # noqa: E402
import numpy as np  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_albedo_quadrature as baq  # noqa: E402
from bench_eval import _loadavg, hemisphere_directions, machine_info, time_interleaved  # noqa: E402
from bench_fit_batch import errors as fit_errors  # noqa: E402
from bench_fit_batch import make_problems, scipy_loop  # noqa: E402

import brdf_fit  # noqa: E402
from brdf_fit import registry  # noqa: E402
from brdf_fit.core import spectra  # noqa: E402
from brdf_fit.core.fresnel import (  # noqa: E402
    ConductorFresnel,
    DielectricFresnel,
    SchlickFresnel,
    ior_from_f0,
)
from brdf_fit.core.microfacet import GGX, SmithHeightCorrelated  # noqa: E402
from brdf_fit.core.quadrature import gauss_legendre_hemisphere  # noqa: E402
from brdf_fit.data import GonioData  # noqa: E402
from brdf_fit.fitting.batch import fit_batch  # noqa: E402
from brdf_fit.fitting.single import fit  # noqa: E402
from brdf_fit.models import MicrofacetBRDF  # noqa: E402
from brdf_fit.tables.dfg import dfg_table, dfg_values  # noqa: E402
from brdf_fit.verify import catalogue  # noqa: E402
from brdf_fit.verify.albedo import directional_albedo  # noqa: E402

SEED = 20261203
F32 = jnp.float32
#: item 1: a float64 output counts as "~0" (excluded from the relative error) when
#: |f64| <= ZERO_REL * max|f64| of that model on the pairs (or is exactly 0)
ZERO_REL = 1e-6
METALS = (("Au", "gold"), ("Cu", "copper"), ("Ag", "silver"), ("Al", "aluminium"))
FRESNELS = ("schlick", "dielectric", "conductor-rgb", "spectral")

FULL = {"n_eval": 65536, "repeats": 7, "min_time": 0.05, "fresnel_alphas": (0.05, 0.2, 0.5),
        "sphere_rings": 8, "quad_alphas": (0.01, 0.1, 0.5), "quad_mus": (0.05, 0.5, 1.0),
        "quad_orders": baq.HALFVECTOR, "gl_orders": baq.GL_PRODUCT,
        "table_sizes": (8, 16, 32, 64, 128, 256), "table_points": 4096,
        "fit_problems": 500, "fit_samples": 300, "fit_repeats": 3}
QUICK = {"n_eval": 4096, "repeats": 3, "min_time": 0.01, "fresnel_alphas": (0.2,),
         "sphere_rings": 3, "quad_alphas": (0.1,), "quad_mus": (0.5,),
         "quad_orders": baq.HALFVECTOR[:3], "gl_orders": baq.GL_PRODUCT[:3],
         "table_sizes": (8, 16), "table_points": 256,
         "fit_problems": 8, "fit_samples": 100, "fit_repeats": 1}


def log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


# ----------------------------------------------------------------------------- 1. models


def measure_models(cfg) -> list[dict]:
    """float32 eval cost (ratio to lambert) and float32-vs-float64 error of every registry model."""
    rng = np.random.default_rng(SEED)
    n = cfg["n_eval"]
    wi32 = jnp.asarray(hemisphere_directions(n, rng), F32)
    wo32 = jnp.asarray(hemisphere_directions(n, rng), F32)
    # the same directions: the float32 vectors, unit only to ~6e-8, renormalised in float64 (a
    # model may use |w| = 1 anywhere; the reference is the value at the direction the rounded
    # vector stands for, so float32 rounding of the input counts as float32 error)
    wi64, wo64 = (w.astype(jnp.float64) / jnp.linalg.norm(w.astype(jnp.float64), axis=-1,
                                                           keepdims=True) for w in (wi32, wo32))
    cases, rows = {}, {}
    for e in registry.entries():
        if "delta" in e.tags:
            continue
        p32 = {k: jnp.asarray(v, F32) for k, v in e.defaults().items()}
        p64 = {k: v.astype(jnp.float64) for k, v in p32.items()}  # the same parameter values

        def ev(p, a, b, e=e):
            return e.build(**p).eval(a, b)

        f = jax.jit(ev)
        out32 = f(p32, wi32, wo32)
        out64 = np.asarray(f(p64, wi64, wo64), np.float64)
        r = np.asarray(out32, np.float64)
        floor = ZERO_REL * np.max(np.abs(out64))
        keep = np.isfinite(out64) & (np.abs(out64) > floor)
        rel = np.abs(r[keep] - out64[keep]) / np.abs(out64[keep])
        rows[e.name] = {
            "model": e.name,
            "dtype_out": str(out32.dtype),
            "kept": int(keep.sum()),
            "total": int(out64.size),
            "nonfinite32": int((~np.isfinite(r)).sum()),
            "max_rel": float(rel.max()) if rel.size else float("nan"),
            "median_rel": float(np.median(rel)) if rel.size else float("nan"),
            "p99_rel": float(np.quantile(rel, 0.99)) if rel.size else float("nan"),
        }
        cases[e.name] = (f, (p32, wi32, wo32))
    log(f"models: compiled {len(cases)}; timing")
    t = time_interleaved(cases, cfg["repeats"], cfg["min_time"])
    base = t["lambert"]["median_s"]
    for name, row in rows.items():
        row["median_s"] = t[name]["median_s"]
        row["best_s"] = t[name]["best_s"]
        row["ratio"] = t[name]["median_s"] / base
        row["ns_per_pair"] = t[name]["median_s"] / n * 1e9
    return sorted(rows.values(), key=lambda r: r["ratio"])


def place_labels(fig, ax, labels, x, y, fontsize=6) -> None:
    """Greedy label placement: each label at the first of a ring of offsets (growing radius)
    whose box overlaps no earlier label (else at the nearest offset); a thin leader line when
    moved away from its point."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    boxes = []
    angles = np.deg2rad([15, -15, 165, -165, 40, -40, 140, -140, 65, -65, 115, -115, 90, -90])
    offsets = [(r * np.cos(t), r * np.sin(t)) for r in (4, 10, 17, 25, 34, 44) for t in angles]
    for i in np.argsort(-np.asarray(y)):
        for k, (dx, dy) in enumerate([*offsets, offsets[0]]):
            ann = ax.annotate(labels[i], (x[i], y[i]), xytext=(dx, dy), textcoords="offset points",
                              fontsize=fontsize, ha="left" if dx >= 0 else "right", va="center",
                              arrowprops=None if k < len(angles) or k == len(offsets) else
                              {"arrowstyle": "-", "lw": 0.3, "color": "0.5"})
            # the text's own box (an Annotation's extent would include its leader line), at the
            # position a draw would give it
            ann.update_positions(renderer)
            bb = matplotlib.text.Text.get_window_extent(ann, renderer).expanded(1.02, 1.15)
            if k == len(offsets) or not any(bb.overlaps(b) for b in boxes):
                boxes.append(bb)
                break
            ann.remove()


def _models_panel(ax, x, y, ym, n):
    ax.loglog(x, y, "o", color="C0", ms=4, label="max relative error")
    ax.loglog(x, ym, ".", color="C1", ms=4, label="median relative error")
    for xi, yi, ymi in zip(x, y, ym, strict=True):
        ax.plot([xi, xi], [ymi, yi], color="0.8", lw=0.6, zorder=0)
    eps = float(np.finfo(np.float32).eps)
    ax.axhline(eps, color="k", lw=0.6, ls=":")
    ax.set_xlabel(f"jit(eval) time, float32, {n} pairs, x lambert (median, same run)")
    ax.set_ylabel("float32 relative error vs float64 (same directions)")
    ax.grid(True, which="both", lw=0.3)


def plot_models(path: Path, rows: list[dict], n: int) -> None:
    """Top: all models; bottom: the dense middle of the cloud enlarged. Each model is labelled
    in one panel (the bottom one when it lies in the enlarged box)."""
    x = np.array([r["ratio"] for r in rows])
    y = np.array([max(r["max_rel"], 1e-9) for r in rows])
    ym = np.array([max(r["median_rel"], 1e-9) for r in rows])
    names = [r["model"] for r in rows]
    xm, yc = np.median(x), np.median(y)
    box = (xm / 3.0, xm * 3.0, yc / 4.0, yc * 4.0)  # the cloud around the median model
    inside = (x >= box[0]) & (x <= box[1]) & (y >= box[2]) & (y <= box[3])
    fig, (top, bot) = plt.subplots(2, 1, figsize=(11, 13), height_ratios=(1, 1.15))
    _models_panel(top, x, y, ym, n)
    top.set_xlim(x.min() / 2.5, x.max() * 2.5)  # room for the labels at both ends
    top.text(x.min(), float(np.finfo(np.float32).eps) * 1.15, "float32 eps", fontsize=7)
    top.add_patch(matplotlib.patches.Rectangle((box[0], box[2]), box[1] - box[0],
                                               box[3] - box[2], fill=False, ls="--", lw=0.8,
                                               color="0.3"))
    top.set_title("Registry models: evaluation cost against float32 error "
                  "(dashed box: enlarged below)")
    top.legend(fontsize=8, loc="upper left")
    _models_panel(bot, x[inside], y[inside], ym[inside], n)
    bot.set_xlim(box[0], box[1])
    bot.set_ylim(box[2], box[3])
    bot.set_title("enlarged: the dashed box (max relative error only)")
    fig.tight_layout()  # before placing labels: their boxes are measured on the final layout
    place_labels(fig, top, [m for m, k in zip(names, inside, strict=True) if not k],
                 x[~inside], y[~inside])
    place_labels(fig, bot, [m for m, k in zip(names, inside, strict=True) if k], x[inside],
                 y[inside], fontsize=7)
    fig.savefig(path, dpi=100)
    plt.close(fig)


# ----------------------------------------------------------------------------- 2. Fresnel


def linear_srgb_to_lab(rgb):
    xyz = colour.RGB_to_XYZ(np.asarray(rgb, np.float64), "sRGB", apply_cctf_decoding=False)
    white = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    return colour.XYZ_to_Lab(xyz, white)


def fresnel_variants(metal: str) -> tuple[dict, np.ndarray, dict]:
    """name -> Fresnel object; the spectral -> linear sRGB matrix; notes on the parameters."""
    wl = spectra.default_wavelengths()
    f0 = np.asarray(spectra.reflectance_rgb(metal, 1.0), np.float64)
    f0_d = np.minimum(f0, spectra.R_CLIP)  # a dielectric reflects < 1 at normal incidence
    eta_rgb, k_rgb = spectra.rgb_nk(metal)
    variants = {
        "schlick": SchlickFresnel(f0=jnp.asarray(f0)),
        "dielectric": DielectricFresnel(eta=jnp.asarray(ior_from_f0(jnp.asarray(f0_d)))),
        "conductor-rgb": ConductorFresnel(eta=jnp.asarray(eta_rgb), k=jnp.asarray(k_rgb)),
        "spectral": spectra.conductor_fresnel(metal, mode="spectral"),
    }
    # spectrum_to_rgb is linear in the spectrum: its (n_wl, 3) matrix, applied after eval
    m = spectra.spectrum_to_rgb(np.eye(wl.size), wl)
    return variants, m, {"f0": f0}


def sphere_colour(model, mus, m=None) -> np.ndarray:
    """Linear sRGB of the rings of an orthographic sphere under a uniform white environment of
    unit radiance: the pixel with view cosine mu shows E(mu) (float64 quadrature)."""
    wo = np.stack([np.sqrt(1 - mus**2) * np.cos(baq.PHI_O), np.sqrt(1 - mus**2) *
                   np.sin(baq.PHI_O), mus], -1)
    e = np.asarray(directional_albedo(model, jnp.asarray(wo)), np.float64)
    return e if m is None else e @ m


def measure_fresnel(cfg) -> dict:
    n = cfg["n_eval"]
    rng = np.random.default_rng(SEED + 1)
    wi = jnp.asarray(hemisphere_directions(n, rng), F32)
    wo = jnp.asarray(hemisphere_directions(n, rng), F32)
    # rings of equal projected area: rho^2 uniform, mu = sqrt(1 - rho^2)
    rho2 = (np.arange(cfg["sphere_rings"]) + 0.5) / cfg["sphere_rings"]
    mus = np.sqrt(1.0 - rho2)
    alpha_t = 0.2
    out = {"metals": {}, "timing": None, "mus": mus.tolist(), "alphas": cfg["fresnel_alphas"]}
    cases = {}
    for metal, label in METALS:
        variants, m, notes = fresnel_variants(metal)
        res = {"label": label, "f0": notes["f0"].tolist(), "dE": {}}
        rgb = {}
        for name, fr in variants.items():
            cols = []
            for a in cfg["fresnel_alphas"]:
                model = MicrofacetBRDF(GGX(jnp.asarray(a)), SmithHeightCorrelated(), fr)
                cols.append(sphere_colour(model, mus, m if name == "spectral" else None))
            rgb[name] = np.stack(cols)  # (alphas, rings, 3)
        lab_ref = linear_srgb_to_lab(rgb["spectral"])
        for name in FRESNELS:
            de = colour.delta_E(linear_srgb_to_lab(rgb[name]), lab_ref, method="CIE 2000")
            mean_rgb = rgb[name].mean(axis=1)  # the sphere's mean colour (equal-area rings)
            de_mean = colour.delta_E(linear_srgb_to_lab(mean_rgb),
                                     linear_srgb_to_lab(rgb["spectral"].mean(axis=1)),
                                     method="CIE 2000")
            res["dE"][name] = {"max": float(np.max(de)), "mean": float(np.mean(de)),
                               "per_alpha_max": np.max(de, axis=1).tolist(),
                               "sphere_mean_colour": np.atleast_1d(de_mean).tolist()}
        res["rgb_mean_spectral"] = rgb["spectral"].mean(axis=1).tolist()
        out["metals"][metal] = res
        if metal == "Au":  # timing on one metal: the cost does not depend on the values
            for name, fr in variants.items():
                model = brdf_fit.astype(
                    MicrofacetBRDF(GGX(jnp.asarray(alpha_t)), SmithHeightCorrelated(), fr), F32)
                if name == "spectral":
                    mj = jnp.asarray(m, F32)
                    fn = jax.jit(lambda mdl, a, b, mj=mj: mdl.eval(a, b) @ mj)
                else:
                    fn = jax.jit(lambda mdl, a, b: mdl.eval(a, b))
                y = fn(model, wi, wo)
                if y.dtype != F32 or y.shape != (n, 3):
                    raise AssertionError(f"fresnel {name}: {y.dtype} {y.shape}")
                cases[name] = (fn, (model, wi, wo))
        log(f"fresnel: {metal} done")
    t = time_interleaved(cases, cfg["repeats"], cfg["min_time"])
    base = t["schlick"]["median_s"]
    out["timing"] = {k: {"median_s": v["median_s"], "best_s": v["best_s"],
                         "ratio": v["median_s"] / base, "ns_per_pair": v["median_s"] / n * 1e9}
                     for k, v in t.items()}
    out["n"] = n
    out["alpha_timing"] = alpha_t
    return out


def plot_fresnel(path: Path, res: dict) -> None:
    fig, ax = plt.subplots(figsize=(8, 5.5))
    markers = {"Au": "o", "Cu": "s", "Ag": "^", "Al": "D"}
    colours = {"schlick": "C0", "dielectric": "C1", "conductor-rgb": "C2", "spectral": "C3"}
    xs, ys, labels = [], [], []
    for metal, r in res["metals"].items():
        for name in FRESNELS[:-1]:
            x, y = res["timing"][name]["ratio"], max(r["dE"][name]["max"], 1e-3)
            ax.loglog(x, y, markers[metal], color=colours[name], ms=6, mfc="none", mew=1.3)
            xs.append(x)
            ys.append(y)
            labels.append(metal)
    spec_x = res["timing"]["spectral"]["ratio"]
    ax.axvline(spec_x, color=colours["spectral"], lw=1.2)
    ax.text(spec_x, 1.5e-3, " spectral\n reference\n (dE00 = 0)", fontsize=7,
            color=colours["spectral"])
    for name in FRESNELS:
        ax.plot([], [], "s", color=colours[name],
                label=f"{name} ({res['timing'][name]['ratio']:.2f}x Schlick)")
    for metal, mk in markers.items():
        ax.plot([], [], mk, color="0.4", mfc="none", label=metal)
    ax.axhline(1.0, color="k", lw=0.6, ls=":")
    ax.text(spec_x / 1.05, 1.08, "dE00 = 1 (just noticeable)", fontsize=7, ha="right")
    ax.set_xlim(min(xs) / 1.5, spec_x * 1.6)
    ax.set_ylim(1e-3, max(ys) * 3)
    ax.set_xlabel(f"GGX BRDF eval time, float32, {res['n']} pairs, x Schlick (median)")
    ax.set_ylabel("max CIEDE2000 vs spectral (sphere rings x alphas)")
    ax.set_title("Fresnel variants: cost against colour error (white-lit GGX sphere)")
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    place_labels(fig, ax, labels, xs, ys, fontsize=7)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------- 3. quadrature


def measure_quadrature(cfg) -> dict:
    refs, rows = {}, []
    t0 = time.perf_counter()
    for a in cfg["quad_alphas"]:
        for mu in cfg["quad_mus"]:
            refs[(a, mu)] = baq.reference(a, mu)
    t_ref = time.perf_counter() - t0
    for a in cfg["quad_alphas"]:
        model = baq.model_for(a)
        for mu in cfg["quad_mus"]:
            wo = jnp.asarray(baq.view(mu))
            for nt, nph in cfg["quad_orders"]:
                e = float(directional_albedo(model, wo, n_theta=nt, n_phi=nph))
                rows.append({"method": "halfvector (directional_albedo)", "alpha": a, "mu": mu,
                             "n": nt * nph, "order": f"{nt} x {nph}",
                             "err": abs(e - refs[(a, mu)])})
            for n_mu, nph in cfg["gl_orders"]:
                r = gauss_legendre_hemisphere(n_mu, nph)
                e = float(baq._rule_value(model, r.directions, r.weights, wo))
                rows.append({"method": "gauss-legendre x trapezoid", "alpha": a, "mu": mu,
                             "n": n_mu * nph, "order": f"{n_mu} x {nph}",
                             "err": abs(e - refs[(a, mu)])})
    return {"refs": {f"{a}/{mu}": v for (a, mu), v in refs.items()}, "rows": rows,
            "t_ref": t_ref}


def plot_quadrature(path: Path, res: dict, cfg) -> None:
    fig, ax = plt.subplots(figsize=(7.5, 5))
    styles = {"halfvector (directional_albedo)": "-", "gauss-legendre x trapezoid": "--"}
    k = 0
    for a in cfg["quad_alphas"]:
        for mu in cfg["quad_mus"]:
            c = f"C{k % 10}"
            k += 1
            for method, ls in styles.items():
                pts = sorted((r["n"], max(r["err"], 1e-17)) for r in res["rows"]
                             if r["method"] == method and r["alpha"] == a and r["mu"] == mu)
                ax.loglog(*zip(*pts, strict=True), ls, marker="o", ms=3, color=c, lw=1,
                          label=f"a={a:g}, mu={mu:g}" if method.startswith("half") else None)
    ax.plot([], [], "k-", label="half-vector rule")
    ax.plot([], [], "k--", label="GL x trapezoid")
    ax.axvline(48 * 64, color="0.5", lw=0.6, ls=":")
    ax.set_xlabel("BRDF evaluations per albedo (quadrature order n_theta x n_phi)")
    ax.set_ylabel("|E - E_ref| (SciPy adaptive reference)")
    ax.set_title("GGX directional albedo (F = 1): quadrature order against error")
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------- 4. tables


def measure_tables(cfg) -> dict:
    rng = np.random.default_rng(SEED + 2)
    r = rng.random(cfg["table_points"])
    mu = rng.random(cfg["table_points"])
    t0 = time.perf_counter()
    A_ref, B_ref = dfg_values(mu, r * r)
    t_ref = time.perf_counter() - t0
    rows = []
    for size in cfg["table_sizes"]:
        t0 = time.perf_counter()
        tab = dfg_table(size, error_estimate=False)
        t_build = time.perf_counter() - t0
        vals = np.asarray(tab.values)
        # inside the span of the texel centres on both axes (outside: clamped to the edge texel)
        nr, nm = tab.axis("roughness").nodes(), tab.axis("mu").nodes()
        inner = (r >= nr[0]) & (r <= nr[-1]) & (mu >= nm[0]) & (mu <= nm[-1])
        for order in (1, 3):
            out = np.asarray(tab.lookup(jnp.asarray(r), jnp.asarray(mu), order=order))
            dd = np.maximum(np.abs(out[:, 0] - A_ref), np.abs(out[:, 1] - B_ref))
            d = np.concatenate([out[:, 0] - A_ref, out[:, 1] - B_ref])
            w = int(np.argmax(dd))
            rows.append({"size": size, "order": order, "max": float(np.abs(d).max()),
                         "max_inner": float(dd[inner].max()) if inner.any() else float("nan"),
                         "inner_frac": float(inner.mean()),
                         "worst_r_mu": (float(r[w]), float(mu[w])),
                         "rms": float(np.sqrt(np.mean(d * d))),
                         "bytes_f32": int(vals[..., :2].size * 4),
                         "bytes_f16": int(vals[..., :2].size * 2),
                         "build_s": t_build})
        log(f"tables: {size} x {size} built in {t_build:.2f} s")
    return {"rows": rows, "t_ref": t_ref, "points": cfg["table_points"]}


def plot_tables(path: Path, res: dict) -> None:
    fig, ax = plt.subplots(figsize=(7.5, 5))
    for order, c in ((1, "C0"), (3, "C3")):
        pts = [r for r in res["rows"] if r["order"] == order]
        name = "linear" if order == 1 else "cubic"
        x = [r["bytes_f32"] / 1024 for r in pts]
        ax.loglog(x, [r["max"] for r in pts], "o-", color=c, label=f"{name}: max, all points")
        ax.loglog(x, [r["max_inner"] for r in pts], "s--", color=c,
                  label=f"{name}: max, inside the texel-centre span")
        ax.loglog(x, [r["rms"] for r in pts], "^:", color=c, label=f"{name}: RMS, all points")
        if order == 1:
            for r, xi in zip(pts, x, strict=True):
                ax.annotate(f"{r['size']}^2", (xi, r["max"]), fontsize=7, xytext=(3, 3),
                            textcoords="offset points")
    ax.set_xlabel("table memory, KiB (A and B, float32)")
    ax.set_ylabel(f"|lookup - quadrature| at {res['points']} random points")
    ax.set_title("Split-sum DFG table: size against interpolation error")
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------- 5. fitting


def measure_fitting(cfg) -> dict:
    B, M = cfg["fit_problems"], cfg["fit_samples"]
    wi, wo, v, ta, tf = make_problems(B, M, seed=SEED + 3)
    res = {}
    # fit_batch: first call (compiles) and warm calls
    t0 = time.perf_counter()
    r = fit_batch(wi, wo, v, "ggx")
    first = time.perf_counter() - t0
    warm = []
    for _ in range(cfg["fit_repeats"]):
        t0 = time.perf_counter()
        r = fit_batch(wi, wo, v, "ggx")
        warm.append(time.perf_counter() - t0)
    res["fit_batch"] = {"seconds": float(np.median(warm)), "first_s": first,
                        "converged": float(np.mean(r.converged)),
                        **fit_errors(np.asarray(r.params["alpha"]), np.asarray(r.params["f0"]),
                                     ta, tf)}
    log(f"fitting: fit_batch {np.median(warm):.2f} s for {B}")
    # single fit loop (the first fit compiles; timed separately)
    chans = ("R", "G", "B")
    t0 = time.perf_counter()
    fit(GonioData(wi[0], wo[0], v[0], channels=chans), "ggx")
    first = time.perf_counter() - t0
    alpha, f0, conv = [], [], []
    t0 = time.perf_counter()
    for b in range(B):
        fr = fit(GonioData(wi[b], wo[b], v[b], channels=chans), "ggx")
        alpha.append(float(np.asarray(fr.params["alpha"])))
        f0.append(np.asarray(fr.params["f0"], np.float64))
        conv.append(bool(fr.converged))
    dt = time.perf_counter() - t0
    res["fit loop"] = {"seconds": dt, "first_s": first, "converged": float(np.mean(conv)),
                       **fit_errors(np.asarray(alpha), np.asarray(f0), ta, tf)}
    log(f"fitting: fit loop {dt:.2f} s")
    # scipy least_squares loop from the registry defaults (bench_fit_batch.scipy_loop)
    for method in ("trf", "lm"):
        s = scipy_loop(wi, wo, v, np.arange(B), method)
        res[f"scipy-{method}"] = {"seconds": s["seconds"], "first_s": None,
                                  "converged": float(np.mean(s["status"] > 0)),
                                  **fit_errors(s["alpha"], s["f0"], ta, tf)}
        log(f"fitting: scipy-{method} {s['seconds']:.2f} s")
    for k in res:
        res[k]["ms_per_fit"] = res[k]["seconds"] / B * 1e3
    return {"methods": res, "problems": B, "samples": M}


def plot_fitting(path: Path, res: dict) -> None:
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for i, (name, r) in enumerate(res["methods"].items()):
        c = f"C{i}"
        ax.loglog(r["ms_per_fit"], r["alpha_rel_median"], "o", color=c, ms=7,
                  label=f"{name}: median")
        ax.loglog(r["ms_per_fit"], r["alpha_rel_p90"], "v", color=c, ms=6, alpha=0.6)
        ax.loglog(r["ms_per_fit"], r["alpha_rel_max"], "x", color=c, ms=6, alpha=0.6)
    ax.plot([], [], "kv", alpha=0.6, label="p90")
    ax.plot([], [], "kx", alpha=0.6, label="max")
    ax.set_xlabel("wall time per fit, ms (warm; same problems)")
    ax.set_ylabel("|alpha / alpha_true - 1|")
    ax.set_title(f"GGX fits ({res['problems']} problems, {res['samples']} samples, 1% noise)")
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    m = res["methods"]
    place_labels(fig, ax, list(m), [r["ms_per_fit"] for r in m.values()],
                 [r["alpha_rel_median"] for r in m.values()], fontsize=7)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------- markdown


def g(x, d=3):
    if x is None:
        return "-"
    if isinstance(x, float) and math.isnan(x):
        return "nan"
    return f"{x:.{d}g}"


def headline_findings(models, fres, quad, tables, fitting) -> list[str]:
    by = {r["model"]: r for r in models}
    worst = max(models, key=lambda r: r["max_rel"] if not math.isnan(r["max_rel"]) else -1)
    slow = models[-1]
    meds = sorted(r["median_rel"] for r in models)
    n_eps = sum(r["max_rel"] <= 1e-5 for r in models)
    lines = [
        f"- **Cost**: {len(models)} models span {models[0]['ratio']:.2f}x to "
        f"{slow['ratio']:.1f}x Lambert's float32 `jit(eval)` time (slowest: `{slow['model']}`; "
        f"`ggx` {by['ggx']['ratio']:.2f}x, `ggx-conductor` {by['ggx-conductor']['ratio']:.2f}x)."
        f" **float32 error**: median relative error per model {meds[0]:.1g} to {meds[-1]:.1g}; "
        f"{n_eps} of {len(models)} models stay within 1e-5 max relative error, the worst is "
        f"`{worst['model']}` ({worst['max_rel']:.2g} max, {worst['median_rel']:.2g} median).",
    ]
    t = fres["timing"]

    def worst_de(name):
        m = max(fres["metals"], key=lambda k: fres["metals"][k]["dE"][name]["max"])
        rest = max((fres["metals"][k]["dE"][name]["max"] for k in fres["metals"] if k != m),
                   default=float("nan"))
        return f"{fres['metals'][m]['dE'][name]['max']:.2g} (worst {m}; others <= {rest:.2g})"

    lines.append(
        f"- **Fresnel** (max CIEDE2000 of a white-lit GGX sphere against the spectral conductor, "
        f"which costs {t['spectral']['ratio']:.2f}x Schlick): per-channel exact conductor "
        f"{t['conductor-rgb']['ratio']:.2f}x Schlick, dE00 {worst_de('conductor-rgb')}; Schlick "
        f"1x, dE00 {worst_de('schlick')}; exact dielectric with the same f0 "
        f"{t['dielectric']['ratio']:.2f}x, dE00 {worst_de('dielectric')}.")
    hv = [r for r in quad["rows"] if r["method"].startswith("half")]
    dflt = [r["err"] for r in hv if r["n"] == 48 * 64]
    fb = fitting["methods"]
    best_scipy = min(("scipy-trf", "scipy-lm"), key=lambda k: fb[k]["seconds"])
    tb = {(r["size"], r["order"]): r for r in tables["rows"]}
    s128 = 128 if (128, 1) in tb else max(s for s, _ in tb)
    quad_txt = (f"the default albedo rule (48 x 64) is within {max(dflt):.1g} of the SciPy "
                f"reference" if dflt else "the default albedo rule (48 x 64) was not run")
    lines.append(
        f"- **Quadrature / tables / fitting**: {quad_txt}; a {s128}^2 DFG table "
        f"({tb[(s128, 1)]['bytes_f32'] / 1024:.0f} KiB float32) interpolates to "
        f"{tb[(s128, 1)]['max']:.1g} (linear) / {tb[(s128, 3)]['max']:.1g} (cubic) max error "
        f"over random points ({tb[(s128, 1)]['max_inner']:.1g} / "
        f"{tb[(s128, 3)]['max_inner']:.1g} inside the span of its texel centres); "
        f"`fit_batch` takes {fb['fit_batch']['ms_per_fit']:.2g} ms per fit (warm; its first "
        f"call, with compilation, {fb['fit_batch']['first_s']:.1f} s) against "
        f"{fb[best_scipy]['ms_per_fit']:.2g} ms for {best_scipy} "
        f"({fb[best_scipy]['seconds'] / fb['fit_batch']['seconds']:.1f}x) and "
        f"{fb['fit loop']['ms_per_fit']:.2g} ms for a `fit` loop; relative alpha error median "
        f"{fb['fit_batch']['alpha_rel_median']:.2g} / {fb[best_scipy]['alpha_rel_median']:.2g} / "
        f"{fb['fit loop']['alpha_rel_median']:.2g}, max {fb['fit_batch']['alpha_rel_max']:.2g} / "
        f"{fb[best_scipy]['alpha_rel_max']:.2g} / {fb['fit loop']['alpha_rel_max']:.2g} "
        "(fit_batch / scipy / fit loop).")
    return lines


def write_report(out: Path, command: str, info: dict, cfg, quick: bool, models, fres, quad,
                 tables, fitting, timings) -> None:
    L = [
        "# brdf_fit: speed against error",
        "",
        "Generated by",
        "",
        "```",
        command,
        "```",
        "",
        f"- date: {info['date_utc']}; total run time {timings['total']:.0f} s"
        + (" (**--quick: smoke-test sizes, not the reference numbers**)" if quick else ""),
        f"- CPU: {info['cpu_model']} ({info['cpu_count']} logical cores, {info['cpus_usable']} "
        f"usable); {info['platform']}, Python {info['python']}",
        f"- jax {info['jax']} (jaxlib {info['jaxlib']}, {', '.join(info['jax_devices'])}), "
        f"numpy {info['numpy']}, colour-science {colour.__version__}, brdf_fit "
        f"{info['brdf_fit']}; x64 enabled (float64 references), float32 measured by explicit "
        "casts",
        f"- load average (1, 5, 15 min) at start {info['loadavg_start']}, at end "
        f"{info['loadavg_end']}; CPU busy just before the start {info['cpu_busy_before_start']}."
        " The machine is shared: absolute times are upper bounds; the claims below are ratios "
        "measured in this run (interleaved samples where stated).",
        "",
        "## Headline",
        "",
        "![cost against float32 error](report/models.png)",
        "",
        *headline_findings(models, fres, quad, tables, fitting),
        "",
    ]
    # 1
    L += [
        "## 1. Evaluation cost against float32 error, per registry model",
        "",
        f"Every non-delta registry entry at its defaults; `jit(lambda p, wi, wo: "
        "entry.build(**p).eval(wi, wo))` with the parameters as traced arguments, on "
        f"{cfg['n_eval']} pairs uniform over the upper hemisphere (seeded). Time: median of "
        f"{cfg['repeats']} samples interleaved across all models "
        f"(`bench_eval.time_interleaved`, each sample >= {cfg['min_time']} s of calls), as a "
        "ratio to `lambert`'s median. Error: the same function in float64 at the same "
        "directions (the float32 pairs renormalised in float64: a float32 unit vector is unit "
        "only to ~6e-8, and a model may rely on |w| = 1 anywhere, so the reference is the value "
        "at the direction the rounded vector stands for) and the same parameter values; "
        f"relative error |f32 - f64| / |f64| over every output channel, **excluding entries whose "
        f"float64 value is exactly 0 or has |f64| <= {ZERO_REL:g} x (the model's max |f64| on "
        "these pairs)** (the `kept` column counts the rest).",
        "",
        "| model | time x lambert | ns/pair | max rel. error | p99 | median | kept / total "
        "| f32 non-finite | output dtype |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in models:
        L.append(f"| `{r['model']}` | {r['ratio']:.2f} | {r['ns_per_pair']:.1f} | "
                 f"{g(r['max_rel'], 2)} | {g(r['p99_rel'], 2)} | {g(r['median_rel'], 2)} | "
                 f"{r['kept']} / {r['total']} | {r['nonfinite32']} | {r['dtype_out']} |")
    L += ["", "![models](report/models.png)", ""]
    # 2
    t = fres["timing"]
    L += [
        "## 2. Fresnel variants: cost against colour error",
        "",
        "`MicrofacetBRDF(GGX(alpha), SmithHeightCorrelated(), fresnel)` with four Fresnel terms "
        "per metal (optical constants: `brdf_fit/resources/nk`, via `brdf_fit.core.spectra`):",
        "",
        "- `schlick`: `SchlickFresnel(f0)`, f0 = `reflectance_rgb(metal, 1)` (the spectral "
        "normal-incidence colour, linear sRGB);",
        f"- `dielectric`: exact `DielectricFresnel(eta = ior_from_f0(min(f0, {spectra.R_CLIP})))`"
        " per channel (real index with the same normal reflectance);",
        "- `conductor-rgb`: exact conductor with the per-channel effective n + ik of "
        "`spectra.rgb_nk` (fitted to the spectral colour over all angles);",
        "- `spectral`: exact conductor at 41 wavelengths (380-780 nm), integrated to linear sRGB "
        "under D65 (`spectrum_to_rgb`, applied as its 41 x 3 matrix): **the reference**.",
        "",
        "Note: `rgb_nk` fits a real conductor, which reflects at most 1; a channel whose spectral "
        f"sRGB reflectance exceeds 1 (gold's red) is fitted to a curve clipped at {spectra.R_CLIP}"
        " (see `spectra.rgb_nk`), while `schlick` takes the unclipped f0 "
        "(Au f0 = " + ", ".join(f"{x:.3f}" for x in fres["metals"].get("Au", {}).get("f0", []))
        + ").",
        "",
        f"Colour: a sphere under a uniform white environment (unit radiance), seen "
        f"orthographically; the ring of view cosine mu shows the directional albedo E(mu) "
        f"(`directional_albedo`, float64). {len(fres['mus'])} equal-area rings "
        f"(mu = {', '.join(f'{m:.2f}' for m in fres['mus'])}) x alpha in "
        f"{', '.join(str(a) for a in fres['alphas'])}. Linear sRGB -> XYZ -> CIELAB (D65), "
        "CIEDE2000 with `colour.delta_E(..., method='CIE 2000')` against the spectral variant.",
        "",
        f"Cost: `jit` of the BRDF eval (spectral: eval of 41 channels and the matrix product), "
        f"float32, {fres['n']} pairs, alpha = {fres['alpha_timing']}, median of {cfg['repeats']} "
        "interleaved samples, ratio to Schlick.",
        "",
        "| variant | time x schlick | ns/pair | " + " | ".join(
            f"{m} max dE00 (mean)" for m in fres["metals"]) + " |",
        "|---|---:|---:|" + "---:|" * len(fres["metals"]),
    ]
    for name in FRESNELS:
        cells = [f"{fres['metals'][m]['dE'][name]['max']:.2f} "
                 f"({fres['metals'][m]['dE'][name]['mean']:.2f})" for m in fres["metals"]]
        L.append(f"| {name} | {t[name]['ratio']:.2f} | {t[name]['ns_per_pair']:.1f} | "
                 + " | ".join(cells) + " |")
    L += ["", "Max dE00 per alpha (" + ", ".join(str(a) for a in fres["alphas"]) + "):", "",
          "| variant | " + " | ".join(fres["metals"]) + " |",
          "|---|" + "---|" * len(fres["metals"])]
    for name in FRESNELS[:-1]:
        L.append(f"| {name} | " + " | ".join(
            " / ".join(f"{x:.2f}" for x in fres["metals"][m]["dE"][name]["per_alpha_max"])
            for m in fres["metals"]) + " |")
    L += ["", "dE00 of the sphere's average colour (mean over the equal-area rings), per alpha "
          "(" + ", ".join(str(a) for a in fres["alphas"]) + "):", "",
          "| variant | " + " | ".join(fres["metals"]) + " |",
          "|---|" + "---|" * len(fres["metals"])]
    for name in FRESNELS[:-1]:
        L.append(f"| {name} | " + " | ".join(
            " / ".join(f"{x:.2f}" for x in fres["metals"][m]["dE"][name]["sphere_mean_colour"])
            for m in fres["metals"]) + " |")
    L += ["", "![fresnel](report/fresnel.png)", ""]
    # 3
    hv = sorted({(r["n"], r["order"]) for r in quad["rows"] if r["method"].startswith("half")})
    combos = [(a, mu) for a in cfg["quad_alphas"] for mu in cfg["quad_mus"]]
    L += [
        "## 3. Quadrature order against albedo error",
        "",
        "GGX, height-correlated Smith, F = 1 (`bench_albedo_quadrature.model_for`), view azimuth "
        f"{baq.PHI_O} rad. `directional_albedo(model, wo, n_theta, n_phi)` (the half-vector rule; "
        "default 48 x 64) and, for comparison, a Gauss-Legendre x trapezoid product rule, "
        "against the nested adaptive SciPy quadrature of `bench_albedo_quadrature.reference` "
        f"(tolerance 1e-11; {quad['t_ref']:.1f} s for {len(quad['refs'])} values).",
        "",
        "| half-vector order | evaluations | " + " | ".join(
            f"a={a:g} mu={mu:g}" for a, mu in combos) + " |",
        "|---|---:|" + "---:|" * len(combos),
    ]
    by = {(r["method"], r["alpha"], r["mu"], r["n"]): r["err"] for r in quad["rows"]}
    for n, order in hv:
        L.append(f"| {order} | {n} | " + " | ".join(
            f"{by[('halfvector (directional_albedo)', a, mu, n)]:.1e}" for a, mu in combos) + " |")
    gl = sorted({(r["n"], r["order"]) for r in quad["rows"] if r["method"].startswith("gauss")})
    L += ["", "| GL x trapezoid order | evaluations | " + " | ".join(
        f"a={a:g} mu={mu:g}" for a, mu in combos) + " |", "|---|---:|" + "---:|" * len(combos)]
    for n, order in gl:
        L.append(f"| {order} | {n} | " + " | ".join(
            f"{by[('gauss-legendre x trapezoid', a, mu, n)]:.1e}" for a, mu in combos) + " |")
    L += ["", "![quadrature](report/quadrature.png)", ""]
    # 4
    L += [
        "## 4. Table size against interpolation error and memory",
        "",
        f"`dfg_table(size)` (split-sum A, B; height-correlated GGX; texel centres; alpha = r^2; "
        "48 x 64 half-vector rule per texel), looked up with "
        f"`Table.lookup(r, mu, order=1 | 3)` at {tables['points']} uniform random (r, mu) in "
        "[0, 1]^2, against `dfg_values` computed "
        f"directly at those points with the same rule ({tables['t_ref']:.1f} s). Errors over A "
        "and B. Memory: the A and B values only (2 channels), float32 and float16.",
        "",
        "`max error` is over every point; `inside max` only over the points within the span of "
        "the texel centres on both axes (`inside` = their fraction; outside it the lookup clamps "
        "to the edge texel); `worst at` = (r, mu) of the largest error.",
        "",
        "| size | lookup | max error | worst at (r, mu) | inside max | inside | RMS error "
        "| float32 bytes | float16 bytes | build s |",
        "|---:|---|---:|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in tables["rows"]:
        L.append(f"| {r['size']} | {'linear' if r['order'] == 1 else 'cubic'} | {r['max']:.2e} | "
                 f"({r['worst_r_mu'][0]:.2g}, {r['worst_r_mu'][1]:.2g}) | "
                 f"{r['max_inner']:.2e} | {r['inner_frac']:.0%} | "
                 f"{r['rms']:.2e} | {r['bytes_f32']} | {r['bytes_f16']} | {r['build_s']:.2f} |")
    L += ["", "![tables](report/tables.png)", ""]
    # 5
    fm = fitting["methods"]
    L += [
        "## 5. Fitting time against parameter error",
        "",
        f"{fitting['problems']} synthetic problems from `bench_fit_batch.make_problems` (registry "
        f"`ggx`, alpha and RGB f0 free, {fitting['samples']} random pairs each, 1% lognormal "
        "noise, seeded), all with the `log` metric:",
        "",
        "- `fit_batch`: `fit_batch(wi, wo, v, 'ggx')` with its defaults (grid guess, batch-lm, "
        f"tolerances 1e-10); median of {cfg['fit_repeats']} warm calls, first call (compilation) "
        "listed separately;",
        "- `fit loop`: `fit(GonioData(...), 'ggx')` per problem with its defaults (grid guess, "
        "lm); the first fit (compilation) is timed separately and not in the loop;",
        "- `scipy-trf` / `scipy-lm`: `bench_fit_batch.scipy_loop`, `least_squares` per problem "
        "from the registry defaults with a jitted JAX residual and Jacobian (default tolerances "
        "1e-8), one pass over all problems.",
        "",
        "Errors against the truth: alpha relative, f0 absolute per channel "
        "(`bench_fit_batch.errors`). First-call times include compilation (no persistent "
        "compilation cache in this process: that is only enabled by the `brdf-fit` CLI); they "
        "are the most load-sensitive numbers here.",
        "",
        "| method | total s | ms per fit | first call s | converged | alpha median | alpha p90 "
        "| alpha max | f0 median | f0 p90 | f0 max |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, r in fm.items():
        L.append(f"| {name} | {r['seconds']:.2f} | {r['ms_per_fit']:.3g} | {g(r['first_s'])} | "
                 f"{r['converged']:.1%} | {r['alpha_rel_median']:.2g} | {r['alpha_rel_p90']:.2g} "
                 f"| {r['alpha_rel_max']:.2g} | {r['f0_abs_median']:.2g} | {r['f0_abs_p90']:.2g} "
                 f"| {r['f0_abs_max']:.2g} |")
    L += ["", "![fitting](report/fitting.png)", ""]
    # 6
    L += catalogue_section(models)
    L += ["", "Section run times (s): " + ", ".join(
        f"{k} {v:.0f}" for k, v in timings.items() if k != "total"), ""]
    (out / "REPORT.md").write_text("\n".join(L))


def catalogue_section(models) -> list[str]:
    import json

    doc = json.loads(catalogue.COST_FILE.read_text())
    rel = doc["relative"]
    f32 = {r["model"]: r["ratio"] for r in models}
    pub = {}
    for row in catalogue.table(costs=rel):
        if row["entry"] is not None:
            pub[row["entry"]] = (row["row"], row["published_cost"])
    m = doc.get("machine", {})
    L = [
        "## 6. Catalogue cost table",
        "",
        "**Not re-measured here**: read from `brdf_fit/resources/catalogue_cost.json` (written "
        f"by `{doc.get('command', 'bench_catalogue_cost.py')}` on {m.get('date_utc', '?')}, "
        f"{doc.get('dtype')}, {doc.get('n')} pairs, minimum over {doc.get('rounds')} rounds, "
        f"load average at start {m.get('loadavg_start')}). The last column is item 1's float32 "
        "ratio from this run (median, different statistic and dtype).",
        "",
        "| entry | catalogue row | eval x lambert | eval+grad x lambert | published (Montes & "
        "Urena 2012) | this run, float32 eval x lambert |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for n in sorted(rel, key=lambda k: rel[k]["eval"]):
        row, p = pub.get(n, (None, None))
        here = f"{f32[n]:.2f}" if n in f32 else "-"
        published = "-" if p is None else f"{p:g}x"
        L.append(f"| `{n}` | {row or '-'} | {rel[n]['eval']:.2f} | {rel[n]['eval_grad']:.2f} | "
                 f"{published} | {here} |")
    return L


# ----------------------------------------------------------------------------- main


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (smoke test)")
    ap.add_argument("--out", type=Path, default=None,
                    help="default: benchmarks/results (--quick: a temporary directory, so a "
                         "smoke run never overwrites the committed report)")
    args = ap.parse_args(argv)
    cfg = QUICK if args.quick else FULL
    if args.out is None:
        args.out = (Path(tempfile.gettempdir()) / "brdf_fit_report_quick" if args.quick
                    else Path(__file__).resolve().parent / "results")
    command = "python " + shlex.join(["benchmarks/report.py",
                                      *(sys.argv[1:] if argv is None else argv)])
    info = machine_info()
    log(f"start; load average {info['loadavg_start']}")
    warnings.filterwarnings("ignore", module="colour")
    plots = args.out / "report"
    plots.mkdir(parents=True, exist_ok=True)
    timings = {}
    t_all = time.perf_counter()

    def section(name, fn):
        t0 = time.perf_counter()
        r = fn(cfg)
        timings[name] = time.perf_counter() - t0
        log(f"{name}: {timings[name]:.0f} s")
        return r

    models = section("models", measure_models)
    plot_models(plots / "models.png", models, cfg["n_eval"])
    fres = section("fresnel", measure_fresnel)
    plot_fresnel(plots / "fresnel.png", fres)
    quad = section("quadrature", measure_quadrature)
    plot_quadrature(plots / "quadrature.png", quad, cfg)
    tables = section("tables", measure_tables)
    plot_tables(plots / "tables.png", tables)
    fitting = section("fitting", measure_fitting)
    plot_fitting(plots / "fitting.png", fitting)
    timings["total"] = time.perf_counter() - t_all
    info["loadavg_end"] = _loadavg()
    write_report(args.out, command, info, cfg, args.quick, models, fres, quad, tables, fitting,
                 timings)
    log(f"wrote {args.out / 'REPORT.md'} ({timings['total']:.0f} s); load average "
        f"{info['loadavg_start']} -> {info['loadavg_end']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
