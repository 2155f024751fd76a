"""Split-sum DFG table: time against error, this generator at several quadrature orders against
the engines' estimator, in one run.

    python benchmarks/bench_tables.py [--size 128] [--big 512] [--cube 16,32,64]
                                      [--out benchmarks/results]

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
``A`` and ``B``. Time: wall seconds of the best of three calls after the first (compiled), 2 CPU
cores; the first call's time (compile + run) is listed too. ``dfg_table`` rows time the whole
table the CLI writes (the values and the error estimate), compiled, for each masking.

Fresh processes (the console script ``brdf-fit``, one subprocess each, wall time and its peak
resident memory from ``getrusage(RUSAGE_CHILDREN)``, ``BRDF_FIT_NO_CACHE=1`` so that nothing comes
from the persistent compilation cache): ``lut dfg --size N`` from a cold process (compile
included); ``--big N``: one ``N x N`` DFG table; ``--cube 16,32,64``: the 3-D dielectric
table ``lut albedo cook-torrance --axis mu=N --axis alpha=N --axis eta=N:1.0:3.0`` at each size.
Memory is bounded by the block size (texels are streamed in blocks, :mod:`brdf_fit.tables._stream`),
so the peak should not grow with the table.

Writes ``<out>/tables.md`` and ``<out>/tables.png`` (error against time).
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit.tables.dfg import BLOCK, DFG_MASKINGS, dfg_table, dfg_values


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


def timed(fn, repeats: int = 3):
    """``(result, first call s, best of ``repeats`` further calls s)``: the best, not the mean,
    because the machine is shared and other work only ever adds time."""
    t0 = time.perf_counter()
    fn()
    first = time.perf_counter() - t0
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return out, first, best


def cli_run(args: list[str]) -> dict:
    """Run ``brdf-fit ARGS`` in a fresh process: wall seconds and peak RSS (MiB)."""
    exe = Path(sys.executable).with_name("brdf-fit")
    cmd = [str(exe) if exe.exists() else "brdf-fit", *args, "--quiet"]
    t0 = time.perf_counter()
    # RUSAGE_CHILDREN's ru_maxrss is the largest over all waited children: a small wrapper
    # process runs the one command and reports that command's own peak
    code = ("import resource, subprocess, sys; subprocess.run(sys.argv[1:], check=True, "
            "stdout=subprocess.DEVNULL); "
            "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)")
    # BRDF_FIT_NO_CACHE: no persistent compilation cache, every run compiles (a cold process)
    out = subprocess.run([sys.executable, "-c", code, *cmd], check=True, capture_output=True,
                         text=True, env={**os.environ, "BRDF_FIT_NO_CACHE": "1"})
    return {"command": "brdf-fit " + " ".join(shlex.quote(a) for a in args),
            "s": time.perf_counter() - t0, "peak_rss_mib": int(out.stdout.split()[-1]) / 1024}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--big", type=int, default=512, help="also time one N x N table (0: skip)")
    ap.add_argument("--cube", default="16,32,64",
                    help="sizes N of the N^3 cook-torrance E(mu, alpha, eta) table ('': skip)")
    ap.add_argument("--out", default="benchmarks/results")
    args = ap.parse_args(argv)
    n = args.size
    load0 = os.getloadavg()
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
    tables = []
    for masking in DFG_MASKINGS:
        _, first, second = timed(lambda masking=masking: dfg_table(n, masking))
        tables.append({"masking": masking, "first_s": first, "s": second})
        print(f"dfg_table({n}, {masking!r}): {second:.3f} s compiled, {first:.2f} s first",
              flush=True)
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        jobs = [["lut", "dfg", "--size", str(n), "--masking", m, "-o", f"{tmp}/dfg.npz"]
                for m in DFG_MASKINGS]
        if args.big:
            jobs.append(["lut", "dfg", "--size", str(args.big), "-o", f"{tmp}/dfg_big.npz"])
        for c in [int(x) for x in args.cube.split(",") if x.strip()]:
            jobs.append(["lut", "albedo", "cook-torrance", "--axis", f"mu={c}", "--axis",
                         f"alpha={c}", "--axis", f"eta={c}:1.0:3.0", "-o",
                         f"{tmp}/ct{c}.npz"])
        for job in jobs:
            runs.append(cli_run(job))
            runs[-1]["command"] = runs[-1]["command"].replace(tmp + "/", "")
            sidecar = Path(job[job.index("-o") + 1]).with_suffix(".json")
            meta = json.loads(sidecar.read_text()).get("meta", {})
            runs[-1]["error"] = (meta.get("error_estimate") or {}).get("max_abs")
            print(f"{runs[-1]['command']}: {runs[-1]['s']:.1f} s, peak RSS "
                  f"{runs[-1]['peak_rss_mib']:.0f} MiB", flush=True)
    load = os.getloadavg()

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
        "Seconds: best of three calls after the first (compiled); first call = compile + run.",
        "",
        "| method | seconds | first call s | max error | RMS error |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['method']} | {r['s']:.3f} | {r['first_s']:.2f} | {r['max']:.2e} | "
                     f"{r['rms']:.2e} |")
    lines += ["", f"`dfg_table({n}, masking)` as `brdf-fit lut dfg` computes it (values and "
              "error estimate), seconds of the best of three compiled calls and of the first:", "",
              "| masking | seconds | first call s |", "|---|---|---|"]
    for t in tables:
        lines.append(f"| {t['masking']} | {t['s']:.3f} | {t['first_s']:.2f} |")
    lines += ["", "Fresh processes (`BRDF_FIT_NO_CACHE=1`: compile included, nothing from the "
              "persistent cache), wall seconds and the process's peak resident memory:", "",
              "| command | seconds | peak RSS MiB | error estimate (metadata) |",
              "|---|---|---|---|"]
    for r in runs:
        err = "-" if r["error"] is None else f"{r['error']:.2g}"
        lines.append(f"| `{r['command']}` | {r['s']:.1f} | {r['peak_rss_mib']:.0f} | {err} |")
    lines += ["", f"Load average at the start: {load0[0]:.1f} / {load0[1]:.1f} / {load0[2]:.1f}; "
              f"at the end: {load[0]:.1f} / {load[1]:.1f} / "
              f"{load[2]:.1f} (1 / 5 / 15 min) on {os.cpu_count()} cores: the machine was shared, "
              "so times are upper bounds."]
    (out / "tables.md").write_text("\n".join(lines) + "\n")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 4), layout="constrained")
    ax = fig.subplots()
    for r in rows:
        ax.loglog(r["s"], r["max"], "o" if r["method"].startswith("half") else "s")
        ax.annotate(r["method"], (r["s"], r["max"]), fontsize=7, xytext=(4, 2),
                    textcoords="offset points")
    ax.set_xlabel(f"seconds for a {n} x {n} table (2 shared CPU cores, compiled, best of 3)")
    ax.set_ylabel("max abs error of A, B")
    ax.set_title("DFG table: error against time")
    ax.grid(True, which="both", lw=0.3)
    fig.savefig(out / "tables.png", dpi=110)
    print(f"wrote {out / 'tables.md'} and {out / 'tables.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
