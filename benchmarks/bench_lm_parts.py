"""Where batch-lm's time goes per lane, float32 against float64 (issue 15).

    python benchmarks/bench_lm_parts.py [--problems 16144]

Part 1, one solver step's pieces on GGX (300 direction pairs of one shared geometry, RGB, metric
``log``), vmapped in groups of 8 lanes (``lax.map``) as batch-lm runs them, over 16,384 lanes:
the residual; the residual and its 2 structured tangents (alpha, the f0 channels); and those
with the normal equations, once through :func:`brdf_fit.fitting._lm.normal` (shipped) and once
through the einsum on the (M, C) layout that it used for every dtype before (old). Best of 5
warm calls, microseconds per lane.

Part 2, :func:`brdf_fit.fitting.batch.fit_batch` on ``--problems`` shared-geometry problems (the
``--stream`` benchmark's source), float64 (tolerances 1e-8) and float32 (1e-5), warm: total
seconds, and the guess and first chunk of its rounds.

Writes ``benchmarks/results/lm_parts.md`` and ``lm_parts.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from brdf_fit import registry  # noqa: E402
from brdf_fit.fitting import _lm  # noqa: E402
from brdf_fit.fitting.batch import fit_batch  # noqa: E402
from brdf_fit.fitting.problem import FitProblem  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from bench_fit_batch import TextureSource  # noqa: E402

OUT = Path(__file__).parent / "results"
M, LANES, GROUP = 300, 16384, 8


def old_normal(T, r, Q):
    Q = jnp.asarray(Q, r.dtype)
    G = jnp.einsum("amc,bmc->cab", T, T)
    h = jnp.einsum("amc,mc->ca", T, r)
    return jnp.einsum("cap,cab,cbq->pq", Q, G, Q), jnp.einsum("cap,ca->p", Q, h)


def parts(dt, rng, wi0, wo0):
    entry = registry.get("ggx")
    _, Q = _lm.directions(FitProblem.of("ggx", ("alpha", "f0"), ((), (3,)), metric="log"), 3)
    wi, wo = jnp.asarray(wi0, dt), jnp.asarray(wo0, dt)
    logd = jnp.asarray(rng.normal(size=(LANES, M, 3)) * 0.1 - 1, dt)
    al = jnp.asarray(rng.uniform(0.1, 0.8, LANES), dt)
    f0 = jnp.asarray(rng.uniform(0.1, 0.9, (LANES, 3)), dt)

    def res(a, f, ld):
        return jnp.log(entry.build(alpha=a, f0=f).eval(wi, wo) * wi[:, 2:3]) - ld

    def tangents(a, f, ld):
        r = res(a, f, ld)
        _, ta = jax.jvp(lambda x: res(x, f, ld), (a,), (jnp.ones_like(a),))
        _, tf = jax.jvp(lambda x: res(a, x, ld), (f,), (jnp.ones_like(f),))
        return r, jnp.stack([ta, tf])

    variants = {
        "residual": lambda a, f, ld: jnp.sum(res(a, f, ld) ** 2),
        "residual + 2 tangents": lambda a, f, ld: [jnp.sum(x) for x in tangents(a, f, ld)],
        "+ normal equations (shipped _lm.normal)": lambda a, f, ld: _lm.normal(
            *tangents(a, f, ld)[::-1], Q),
        "+ normal equations (old einsum)": lambda a, f, ld: old_normal(
            *tangents(a, f, ld)[::-1], Q),
    }
    out = {}
    for name, fn in variants.items():
        g = jax.jit(lambda A, F, L, fn=fn: jax.lax.map(
            lambda t: jax.vmap(fn)(*t),
            (A.reshape(-1, GROUP), F.reshape(-1, GROUP, 3), L.reshape(-1, GROUP, M, 3))))
        jax.block_until_ready(g(al, f0, logd))
        ts = []
        for _ in range(5):
            t0 = time.perf_counter()
            jax.block_until_ready(g(al, f0, logd))
            ts.append(time.perf_counter() - t0)
        out[name] = min(ts) / LANES * 1e6
    return out


def batch(src, v, dt, tol):
    kw = dict(rtol=tol, atol=tol, dtype=dt, metric="log")
    fit_batch(src.wi, src.wo, v, "ggx", **kw)  # compile
    t = time.perf_counter()
    r = fit_batch(src.wi, src.wo, v, "ggx", **kw)
    dt_ = time.perf_counter() - t
    guess = sum(x["seconds"] for x in r.rounds if x.get("guess"))
    chunks = [x for x in r.rounds if x.get("lane_steps")]
    first = chunks[0]
    return {"seconds": dt_, "guess_seconds": guess, "first_chunk_seconds": first["seconds"],
            "first_chunk_lane_steps": first["lane_steps"],
            "us_per_lane_step_first_chunk": first["seconds"] / first["lane_steps"] * 1e6,
            "sum_steps": int(r.steps.sum()), "converged": float(np.mean(r.converged)),
            "lane_steps": r.lane_steps()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problems", type=int, default=16144)
    args = ap.parse_args(argv)
    command = "python benchmarks/bench_lm_parts.py" + "".join(
        f" {a}" for a in (argv if argv is not None else sys.argv[1:]))
    load0 = os.getloadavg()
    src = TextureSource(args.problems, M, 20240611)
    res = {"command": command, "date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
           "jax": jax.__version__, "loadavg_start": load0}
    for dt in (jnp.float64, jnp.float32):
        res[f"parts_{dt.__name__}"] = parts(dt, np.random.default_rng(0), src.wi, src.wo)
        print(dt.__name__, res[f"parts_{dt.__name__}"], flush=True)
    v = src(0, args.problems)
    res["fit_batch_float64"] = batch(src, v, jnp.float64, 1e-8)
    res["fit_batch_float32"] = batch(src, v, jnp.float32, 1e-5)
    res["loadavg_end"] = os.getloadavg()
    print(res["fit_batch_float64"], res["fit_batch_float32"], sep="\n")
    OUT.mkdir(exist_ok=True)
    (OUT / "lm_parts.json").write_text(json.dumps(res, indent=1))
    p64, p32 = res["parts_float64"], res["parts_float32"]
    lines = ["# batch-lm per lane: float32 against float64 (issue 15)", "", "Command:", "",
             "```", command, "```", "",
             f"- date: {res['date']}; jax {res['jax']}; load average at start "
             f"{[round(x, 2) for x in load0]}, at end "
             f"{[round(x, 2) for x in res['loadavg_end']]} (2 cores: above ~1 other work "
             "shared the machine)", "",
             f"## One step's pieces (GGX, {M} pairs x RGB, `log`, groups of {GROUP} lanes, "
             f"{LANES} lanes; us per lane, best of 5)", "",
             "| piece | float64 | float32 |", "|---|---:|---:|"]
    lines += [f"| {k} | {p64[k]:.2f} | {p32[k]:.2f} |" for k in p64]
    lines += ["", f"## fit_batch, {args.problems} problems of one shared geometry (warm)", "",
              "| dtype | seconds | guess s | first chunk s | us per lane-step (first chunk) "
              "| steps | converged |", "|---|---:|---:|---:|---:|---:|---:|"]
    for name in ("float64", "float32"):
        b = res[f"fit_batch_{name}"]
        lines.append(f"| {name} | {b['seconds']:.2f} | {b['guess_seconds']:.2f} | "
                     f"{b['first_chunk_seconds']:.2f} | {b['us_per_lane_step_first_chunk']:.1f} "
                     f"| {b['sum_steps']} | {b['converged']:.4f} |")
    (OUT / "lm_parts.md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
