"""Split-sum DFG table: time against error, this generator at several quadrature orders against
the engines' estimator, in one run.

    python benchmarks/bench_tables.py [--size 128] [--big 512] [--out benchmarks/results]

Methods (all for the height-correlated GGX table ``A, B`` at texel centres, ``alpha = r^2``):

``halfvector n_theta x n_phi``  :func:`brdf_fit.tables.dfg.dfg_values` (float64, JAX, jit), the
                                default order is 48 x 64
``hammersley-1024``             the estimator of Karis 2013 (``IntegrateBRDF``), Filament's cmgen
                                and the Khronos glTF-IBL-Sampler, re-implemented from their
                                published description: 1024 points of the Hammersley set
                                (radical inverse base 2), GGX normal-distribution sampling of the
                                half vector, ``l = reflect(v, h)``, weight ``4 V (n.l)(v.h)/(n.h)``
                                for ``n.l > 0``; float32 like the engines (JAX, jit), and float64
``hammersley-8192``             the same with 8192 points (float64)

Reference: the half-vector rule at 96 x 128 nodes (its agreement with SciPy's adaptive quadrature
at spot texels is a test: tests/tables/test_dfg.py). Errors are max and RMS over every texel of
``A`` and ``B``. Time: wall seconds of the second call (compiled), 2 CPU cores; the first call's
time (compile + run) is listed too. ``--big N`` also times one ``N x N`` table of the default
generator and records the process's peak resident memory (``ru_maxrss``), to show that memory is
bounded by the block size (rows are streamed in blocks of ``BLOCK`` texels).

Writes ``<out>/tables.md`` and ``<out>/tables.png`` (error against time).
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import platform
import resource
import shlex
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit.tables.dfg import BLOCK, dfg_values


def hammersley(n: int) -> tuple[np.ndarray, np.ndarray]:
    i = np.arange(n, dtype=np.uint32)
    # radical inverse in base 2 (Van der Corput) by bit reversal
    b = i.copy()
    b = ((b << 16) | (b >> 16)) & 0xFFFFFFFF
    b = ((b & 0x55555555) << 1) | ((b & 0xAAAAAAAA) >> 1)
    b = ((b & 0x33333333) << 2) | ((b & 0xCCCCCCCC) >> 2)
    b = ((b & 0x0F0F0F0F) << 4) | ((b & 0xF0F0F0F0) >> 4)
    b = ((b & 0x00FF00FF) << 8) | ((b & 0xFF00FF00) >> 8)
    return (i + 0.5) / n, b.astype(np.float64) / 2.0**32


def make_estimator(n: int, dtype):
    u1, u2 = (jnp.asarray(u, dtype) for u in hammersley(n))

    @jax.jit
    def estimate(mu, alpha):
        mu = mu[:, None]
        a = alpha[:, None]
        vx, vz = jnp.sqrt(1.0 - mu * mu), mu
        # GGX normal sampling: tan^2(theta_h) = a^2 u / (1 - u) (Walter et al. 2007, eq. 35)
        phi = 2.0 * math.pi * u2
        cos_h = jnp.sqrt((1.0 - u1) / (1.0 + (a * a - 1.0) * u1))
        sin_h = jnp.sqrt(1.0 - cos_h * cos_h)
        hx, hy, hz = sin_h * jnp.cos(phi), sin_h * jnp.sin(phi), cos_h
        voh = vx * hx + vz * hz
        lz = 2.0 * voh * hz - vz
        lx, ly = 2.0 * voh * hx - vx, 2.0 * voh * hy
        a2 = a * a
        p_l = jnp.sqrt(lz * lz + a2 * (lx * lx + ly * ly))
        p_v = jnp.sqrt(vz * vz + a2 * vx * vx)
        vis = 0.5 / (vz * p_l + lz * p_v)
        ok = (lz > 0) & (voh > 0)
        w = jnp.where(ok, 4.0 * vis * lz * voh / hz, 0.0)
        fc = (1.0 - voh) ** 5
        return jnp.mean(w * (1.0 - fc), axis=-1), jnp.mean(w * fc, axis=-1)

    return estimate


def estimator_table(est, mu, alpha, dtype):
    mm, aa = np.meshgrid(mu, alpha)
    out_a, out_b = [], []
    flat_m, flat_a = mm.ravel(), aa.ravel()
    for s in range(0, flat_m.size, BLOCK):
        blk = slice(s, s + BLOCK)
        a_, b_ = est(jnp.asarray(flat_m[blk], dtype), jnp.asarray(flat_a[blk], dtype))
        out_a.append(np.asarray(a_, np.float64))
        out_b.append(np.asarray(b_, np.float64))
    return np.concatenate(out_a).reshape(mm.shape), np.concatenate(out_b).reshape(mm.shape)


def timed(fn):
    t0 = time.perf_counter()
    fn()
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = fn()
    return out, first, time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--big", type=int, default=512, help="also time one N x N table (0: skip)")
    ap.add_argument("--out", default="benchmarks/results")
    args = ap.parse_args(argv)
    n = args.size
    c = (np.arange(n) + 0.5) / n
    mu, alpha = c, c * c
    print(f"reference: halfvector 96 x 128 on {n} x {n}", flush=True)
    t0 = time.perf_counter()
    A_ref, B_ref = dfg_values(mu[None, :], alpha[:, None], n_theta=96, n_phi=128)
    t_ref = time.perf_counter() - t0
    rows = []

    def record(name, A, B, first, second):
        d = np.concatenate([(A - A_ref).ravel(), (B - B_ref).ravel()])
        rows.append({"method": name, "first_s": first, "s": second,
                     "max": float(np.abs(d).max()), "rms": float(np.sqrt(np.mean(d * d)))})
        print(f"{name:28s} {second:8.3f} s  max {rows[-1]['max']:.2e}  rms {rows[-1]['rms']:.2e}",
              flush=True)

    for nt, npf in [(16, 24), (24, 32), (32, 48), (48, 64)]:
        (A, B), first, second = timed(
            lambda nt=nt, npf=npf: dfg_values(mu[None, :], alpha[:, None], n_theta=nt, n_phi=npf))
        record(f"halfvector {nt} x {npf}", A, B, first, second)
    with jax.enable_x64(True):
        for npts, dt, label in [(1024, jnp.float32, "hammersley-1024 float32"),
                                (1024, jnp.float64, "hammersley-1024 float64"),
                                (8192, jnp.float64, "hammersley-8192 float64")]:
            est = make_estimator(npts, dt)
            (A, B), first, second = timed(
                lambda est=est, dt=dt: estimator_table(est, mu, alpha, dt))
            record(label, A, B, first, second)
    big = None
    if args.big:
        nb = args.big
        cb = (np.arange(nb) + 0.5) / nb
        t0 = time.perf_counter()
        dfg_values(cb[None, :], (cb * cb)[:, None])
        big = {"size": nb, "s": time.perf_counter() - t0,
               "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
        print(f"{nb} x {nb}: {big['s']:.1f} s, peak RSS {big['peak_rss_mib']:.0f} MiB", flush=True)

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cmd = "python " + " ".join(shlex.quote(a) for a in [sys.argv[0], *sys.argv[1:]])
    lines = [
        "# Split-sum DFG table: time against error",
        "",
        f"Command: `{cmd}`  ",
        f"Date: {datetime.date.today()}; machine: {platform.machine()}, {os.cpu_count()} CPU "
        f"cores, jax {jax.__version__}, Python {platform.python_version()}.",
        "",
        f"Table: {n} x {n} texels, height-correlated GGX, texel centres, alpha = r^2. Reference: "
        f"half-vector rule 96 x 128 ({t_ref:.1f} s). Errors over every texel of A and B. "
        "Seconds: the second call (compiled); first call = compile + run.",
        "",
        "| method | seconds | first call s | max error | RMS error |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['method']} | {r['s']:.3f} | {r['first_s']:.2f} | {r['max']:.2e} | "
                     f"{r['rms']:.2e} |")
    if big:
        lines += ["", f"One {big['size']} x {big['size']} table (default 48 x 64 rule, blocks of "
                  f"{BLOCK} texels): {big['s']:.1f} s, process peak RSS {big['peak_rss_mib']:.0f} "
                  "MiB (includes the runs above)."]
    (out / "tables.md").write_text("\n".join(lines) + "\n")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 4), layout="constrained")
    ax = fig.subplots()
    for r in rows:
        ax.loglog(r["s"], r["max"], "o" if r["method"].startswith("half") else "s")
        ax.annotate(r["method"], (r["s"], r["max"]), fontsize=7, xytext=(4, 2),
                    textcoords="offset points")
    ax.set_xlabel(f"seconds for a {n} x {n} table (2 CPU cores, compiled)")
    ax.set_ylabel("max abs error of A, B")
    ax.set_title("DFG table: error against time")
    ax.grid(True, which="both", lw=0.3)
    fig.savefig(out / "tables.png", dpi=110)
    print(f"wrote {out / 'tables.md'} and {out / 'tables.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
