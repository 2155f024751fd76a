"""Parity of every Mitsuba-native registry entry with Mitsuba 3 itself: the figure the README's
registry table states.

    python benchmarks/bench_native_parity.py [--pairs 2000] [--out DIR]

For each entry with ``target == "mitsuba"``, at its defaults and at a second parameter set
(``tests/models/test_mitsuba_native.py``'s sets; principled's own file has more), ``eval`` in
float64 at the float32-rounded directions the plugin sees, against the plugin's ``BSDF.eval``
(``scalar_rgb``, float32) at ``--pairs`` random
pairs (cosines uniform in [1e-3, 1]) plus as many grazing ones (one direction at cos 1e-3 ..
0.05): the largest and the median relative difference where Mitsuba's value exceeds 1e-9 of
the set's peak (Mitsuba zeroes D below 1e-20 and float32 flushes far tails).

Writes ``native_parity.md`` and ``native_parity.json`` to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_eval import _loadavg, machine_info  # noqa: E402

from brdf_fit import registry  # noqa: E402
from brdf_fit.convert.mitsuba import mitsuba_eval  # noqa: E402

SECOND = {
    "mitsuba-roughconductor": {"alpha": 0.35, "eta": (1.1, 0.9, 0.5), "k": (4.0, 3.0, 2.5)},
    "mitsuba-roughconductor-beckmann": {"alpha": 0.3},
    "mitsuba-roughconductor-aniso": {"alpha_u": 0.08, "alpha_v": 0.25},
    "mitsuba-roughconductor-beckmann-aniso": {"alpha_u": 0.4, "alpha_v": 0.05},
    "mitsuba-roughplastic": {"alpha": 0.2, "diffuse_reflectance": (0.6, 0.25, 0.1),
                             "int_ior": 1.5},
    "mitsuba-roughplastic-beckmann": {"alpha": 0.45, "int_ior": 1.8},
    "mitsuba-roughplastic-nonlinear": {"alpha": 0.03, "diffuse_reflectance": (0.9, 0.5, 0.2)},
    "mitsuba-principled": {"base_color": (0.8, 0.3, 0.1), "roughness": 0.3, "metallic": 0.4,
                           "specular": 0.7},
    "mitsuba-principled-aniso": {"roughness": 0.4, "anisotropic": 0.7, "metallic": 1.0},
    "mitsuba-principled-full": {"sheen": 0.6, "clearcoat": 0.8, "clearcoat_gloss": 0.5,
                                "flatness": 0.3},
}


def _pairs(rng, n):
    def dirs(mu):
        phi = rng.uniform(0, 2 * np.pi, mu.size)
        s = np.sqrt(1 - mu * mu)
        return np.stack([s * np.cos(phi), s * np.sin(phi), mu], -1)

    wi, wo = dirs(rng.uniform(1e-3, 1, n)), dirs(rng.uniform(1e-3, 1, n))
    g = dirs(np.geomspace(1e-3, 0.05, n))
    o = dirs(rng.uniform(1e-3, 1, n))
    half = n // 2
    return (np.concatenate([wi, g[:half], o[half:]]), np.concatenate([wo, o[:half], g[half:]]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pairs", type=int, default=2000)
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"))
    args = ap.parse_args(argv)
    import mitsuba

    info = machine_info()
    rng = np.random.default_rng(28)
    wi, wo = _pairs(rng, args.pairs)
    rows = []
    for e in registry.entries():
        if e.target != "mitsuba":
            continue
        for label, extra in (("defaults", {}), ("second set", SECOND.get(e.name, {}))):
            full = {**e.defaults(), **{k: np.asarray(v, float) for k, v in extra.items()}}
            # at the inputs Mitsuba sees: its Vector3f holds the directions in float32, and at
            # near-opposite grazing pairs h = normalize(wi + wo) amplifies that rounding
            # (1e-5 .. 6e-5 relative in the value) into differences that are the inputs', not
            # the models'
            ours = np.asarray(jax.jit(lambda m, a, b: m.eval(a, b))(
                e.build(**full), jnp.asarray(wi.astype(np.float32).astype(float)),
                jnp.asarray(wo.astype(np.float32).astype(float))))
            theirs = mitsuba_eval(e.native_export(full), wi, wo)
            keep = np.abs(theirs) > 1e-9 * np.max(np.abs(theirs))
            rel = np.abs(ours - theirs)[keep] / np.abs(theirs)[keep]
            rows.append({"entry": e.name, "set": label, "params": {k: np.asarray(v).tolist()
                                                                    for k, v in extra.items()},
                         "max_rel": float(np.max(rel)), "median_rel": float(np.median(rel)),
                         "n": int(keep.sum())})
            print(f"{e.name} {label}: {rows[-1]['max_rel']:.2e}", file=sys.stderr)
    info["loadavg_end"] = _loadavg()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    command = "python benchmarks/bench_native_parity.py " + shlex.join(argv or sys.argv[1:])
    doc = {"command": command.strip(), "machine": info, "mitsuba": mitsuba.__version__,
           "rows": rows}
    (out / "native_parity.json").write_text(json.dumps(doc, indent=1) + "\n")
    lines = ["# Mitsuba-native entries against Mitsuba " + mitsuba.__version__, "",
             "Command:", "", f"    {doc['command']}", "",
             f"Machine: {info.get('cpu_model')}, {info.get('date_utc')}. Each row: "
             f"{2 * args.pairs} pairs (half random, half grazing), float64 model at the "
             "float32-rounded directions Mitsuba sees, against Mitsuba's float32 `scalar_rgb` "
             "`BSDF.eval`.", "",
             "| entry | parameters | pairs | max relative difference | median |",
             "|---|---|---:|---:|---:|"]
    for r in rows:
        p = ", ".join(f"{k}={v}" for k, v in r["params"].items()) or "defaults"
        lines.append(f"| {r['entry']} | {p} | {r['n']} | {r['max_rel']:.1e} | "
                     f"{r['median_rel']:.1e} |")
    (out / "native_parity.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
