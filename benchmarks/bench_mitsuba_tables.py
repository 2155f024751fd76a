"""Mitsuba 3 roughplastic's tabulated coating terms against the package's converged integrals
(:mod:`brdf_fit.tables.mitsuba`): how close the renderer's tables are, and what the difference
does to the diffuse term.

    python benchmarks/bench_mitsuba_tables.py [--out DIR]

For each distribution (GGX, Beckmann), width alpha and interior index (air outside): the
largest absolute difference of the 64-entry transmittance table ``T``, Mitsuba's ``Fdr_int``
against the converged ``2 Int R(mu) mu dmu``, and the relative change of the diffuse term
(``(F_m - F_c)/(1 - F_m)``), split into what the 64-point mean (instead of an integral) and what
the 128 x 128 rule contribute. The converged references' own accuracy (order doubling) is
reported in the same run.

Writes ``mitsuba_tables.md`` and ``mitsuba_tables.json`` to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_eval import _loadavg, machine_info  # noqa: E402

from brdf_fit.models.mitsuba import AIR_IOR  # noqa: E402
from brdf_fit.tables import mitsuba as tm  # noqa: E402

ALPHAS = (0.01, 0.05, 0.1, 0.2, 0.3, 0.5)
IORS = (1.33, 1.5, 1.8)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"))
    args = ap.parse_args(argv)
    info = machine_info()
    t0 = time.perf_counter()
    rows = []
    for dist in ("ggx", "beckmann"):
        for ior in IORS:
            for a in ALPHAS:
                r = tm.compare(a, ior / AIR_IOR, dist)
                r["int_ior"] = ior
                rows.append(r)
                print(f"{dist} alpha {a} int_ior {ior}: diffuse {r['diffuse_rel_change']:+.4f}",
                      file=sys.stderr)
    # the references' own accuracy: halve every order at two points
    conv = []
    for dist, a in (("ggx", 0.2), ("beckmann", 0.2)):
        hi = tm.converged_tables(a, 1.5 / AIR_IOR, dist)
        lo = tm.converged_tables(a, 1.5 / AIR_IOR, dist, t_order=tm.T_ORDER // 2,
                                 mu_order=tm.FDR_MU_ORDER // 2)
        conv.append({"distribution": dist, "alpha": a,
                     "T_change": float(np.max(np.abs(hi["T"] - lo["T"]))),
                     "Fdr_change": abs(hi["Fdr_int"] - lo["Fdr_int"])})
    info["loadavg_end"] = _loadavg()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    command = "python benchmarks/bench_mitsuba_tables.py " + shlex.join(argv or sys.argv[1:])
    doc = {"command": command.strip(), "machine": info, "rows": rows, "convergence": conv,
           "seconds": time.perf_counter() - t0}
    (out / "mitsuba_tables.json").write_text(json.dumps(doc, indent=1) + "\n")
    lines = ["# Mitsuba 3 roughplastic's tables against converged integrals", "",
             "Command:", "", f"    {doc['command']}", "",
             f"Machine: {info.get('cpu_model')}, {info.get('cpu_count')} cores, "
             f"{info.get('date_utc')}; {doc['seconds']:.0f} s.", "",
             "Mitsuba's tables as `brdf_fit.models.mitsuba` computes them (equal to the "
             "plugin's to float32 rounding); references from `brdf_fit.tables.mitsuba` "
             "(`R` by the package's lobe-adapted albedo quadrature, `2 Int R mu dmu` by "
             "Gauss-Legendre split at the critical cosine, `T` on the package's own "
             "visible-normal sampler at 256 x 256).", "",
             "| distribution | int_ior | alpha | max abs dT | Fdr_int Mitsuba | Fdr_int converged "
             "| diffuse term, Mitsuba vs converged | of which the 128^2 rule |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['distribution']} | {r['int_ior']} | {r['alpha']} | "
                     f"{r['T_max_abs_diff']:.2e} | {r['Fdr_mitsuba']:.5f} | "
                     f"{r['Fdr_converged']:.5f} | {100 * r['diffuse_rel_change']:+.2f}% | "
                     f"{100 * r['diffuse_rel_change_quadrature_only']:+.3f}% |")
    lines += ["", "The rest of the diffuse difference is Mitsuba's estimator of the "
              "hemispherical average: the mean of `mu R(mu)` over 64 equispaced cosines "
              "(endpoints included) instead of the integral.", "",
              "References' own accuracy (every order halved):", ""]
    for c in conv:
        lines.append(f"- {c['distribution']} alpha {c['alpha']}: T changes by "
                     f"{c['T_change']:.1e}, Fdr_int by {c['Fdr_change']:.1e}")
    (out / "mitsuba_tables.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
