"""Texture-scale fitting on 1, 2 and 4 local processes (issue 29): wall time of
``brdf-fit fit-batch --values V.npy --geometry G.npz --out-dir DIR [--processes P]`` on N GGX
problems sharing one geometry, with the maps of every P checked equal to one process's.

    python benchmarks/bench_distributed.py [--problems 1000000] [--samples 300]
                                           [--processes 1 2 4] [--out benchmarks/results]

The problems are :class:`bench_fit_batch.TextureSource`'s (per texel a truth alpha and RGB
f0, 1% lognormal noise), written once to a float64 ``.npy`` in a temporary folder (memory-mapped
by the command; its generation is not timed). Each configuration runs as a fresh ``brdf-fit``
process (the launcher, plus P children for P > 1) with the compilation cache of a warm-up run on
the same block shape, so the figures are fitting and process start, not XLA compilation
(a cold run adds the compilation once per process). CPU seconds are the children's (user +
system, ``RUSAGE_CHILDREN``). Writes ``distributed.md`` and ``distributed.json``.

The projection for 1.7e7 texels (a 4K SVBRDF) assumes what it says: each core fits at the rate
per CPU second measured here with one process, perfect scaling over independent blocks on a
shared filesystem, and the stated per-process start-up (import, compile) paid once.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_latency import _cpu as cpu_name  # noqa: E402  (the CPU's model name)

TEXELS_4K = 4096 * 4096  # 1.68e7


def run(cmd, env) -> tuple[float, float, str]:
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode not in (0, 1):
        raise SystemExit(f"{' '.join(cmd)} failed ({p.returncode}):\n{p.stdout}\n{p.stderr}")
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return wall, cpu, p.stdout


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--problems", type=int, default=1_000_000)
    ap.add_argument("--samples", type=int, default=300)
    ap.add_argument("--processes", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--block-size", type=int, default=None)
    ap.add_argument("--seed", type=int, default=20240611)
    ap.add_argument("--out", default=str(HERE / "results"))
    args = ap.parse_args()
    import jax

    jax.config.update("jax_enable_x64", True)
    from bench_fit_batch import GEN_CHUNK, TextureSource

    tmp = Path(tempfile.mkdtemp(prefix="bench_distributed_"))
    env = dict(os.environ, BRDF_FIT_CACHE_DIR=str(tmp / "cache"))
    env.pop("BRDF_FIT_NO_CACHE", None)
    brdf = [sys.executable, "-m", "brdf_fit.cli"]
    try:
        N, M = args.problems, args.samples
        src = TextureSource(N, M, args.seed)
        t = time.perf_counter()
        vals = np.lib.format.open_memmap(tmp / "values.npy", mode="w+", dtype=np.float64,
                                         shape=(N, M, 3))
        for s in range(0, N, 16 * GEN_CHUNK):
            e = min(N, s + 16 * GEN_CHUNK)
            vals[s:e] = src(s, e)
        vals.flush()
        del vals
        gen_s = time.perf_counter() - t
        np.savez(tmp / "geometry.npz", wi=src.wi, wo=src.wo)
        common = ["fit-batch", "--values", str(tmp / "values.npy"), "--geometry",
                  str(tmp / "geometry.npz"), "--model", "ggx", "--quiet", "--json"]
        if args.block_size:
            common += ["--block-size", str(args.block_size)]
        # warm-up: the block shape compiled once into the shared cache (a small run of the
        # same block size: the default from the memory budget, as the timed runs use)
        from brdf_fit.fitting.stream import block_size_for, plan_blocks

        bs = args.block_size or block_size_for(M, 3)
        bs = plan_blocks(N, bs)[0]
        np.save(tmp / "warm.npy", np.load(tmp / "values.npy", mmap_mode="r")[:bs])
        warm = ["fit-batch", "--values", str(tmp / "warm.npy"), "--geometry",
                str(tmp / "geometry.npz"), "--model", "ggx", "--quiet", "--json",
                "--block-size", str(bs)]
        w_wall, w_cpu, _ = run([*brdf, *warm, "--out-dir", str(tmp / "warm")], env)
        rows, maps = [], {}
        for P in args.processes:
            cmd = [*brdf, *common, "--out-dir", str(tmp / f"run{P}"), "--block-size", str(bs)]
            if P > 1:
                cmd += ["--processes", str(P)]
            load0 = os.getloadavg()
            wall, cpu, out = run(cmd, env)
            load1 = os.getloadavg()
            summary = json.loads(out)
            m = {k: np.load(tmp / f"run{P}" / "maps" / f"{k}.npy")
                 for k in ("params_alpha", "params_f0", "stderr_alpha", "converged")}
            maps[P] = m
            same = all(np.array_equal(m[k], maps[args.processes[0]][k], equal_nan=True)
                       for k in m)
            rows.append({"processes": P, "wall_s": round(wall, 2), "cpu_s": round(cpu, 2),
                         "fits_per_s": round(N / wall, 1), "converged": summary["converged"],
                         "blocks": summary["blocks"], "block_size": summary["block_size"],
                         "equal_to_first": bool(same), "loadavg_start": load0,
                         "loadavg_end": load1})
            print(f"P={P}: {wall:.1f} s wall, {cpu:.1f} s CPU, {N / wall:.0f} fits/s, "
                  f"equal to P={args.processes[0]}: {same}", flush=True)
        base = rows[0]["wall_s"]
        for r in rows:
            r["speedup"] = round(base / r["wall_s"], 3)
            r["efficiency"] = round(base / r["wall_s"] / (r["processes"]
                                                           / rows[0]["processes"]), 3)
        # per core: fits per CPU second of the first run (one process may use a second core
        # for part of XLA's work, so its wall-clock rate would overstate a core)
        per_proc = N / rows[0]["cpu_s"]
        cluster = {"nodes": 16, "processes_per_node": 32}
        procs = cluster["nodes"] * cluster["processes_per_node"]
        startup = w_wall
        proj = TEXELS_4K / (per_proc * procs) + startup
        info = {"date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
                "cpu": cpu_name(), "cores": os.cpu_count(),
                "python": platform.python_version(), "jax": jax.__version__,
                "command": "python benchmarks/bench_distributed.py " + " ".join(sys.argv[1:]),
                "problems": N, "samples": M, "channels": 3, "generation_s": round(gen_s, 1),
                "warmup_wall_s": round(w_wall, 2), "warmup_block": bs}
        res = {"info": info, "runs": rows,
               "projection_4k": {"texels": TEXELS_4K, "cluster": cluster,
                                 "fits_per_cpu_s": round(per_proc, 1),
                                 "startup_s": round(startup, 1),
                                 "projected_wall_s": round(proj, 1)}}
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "distributed.json").write_text(json.dumps(res, indent=1) + "\n")
        lines = [
            "# Texture-scale fitting on several local processes (issue 29)", "",
            f"Command: `{info['command']}`  ",
            f"Date: {info['date']}; CPU: {info['cpu']} ({info['cores']} cores); Python "
            f"{info['python']}, jax {info['jax']}", "",
            f"{N} GGX problems (alpha and RGB f0 free), {M} samples each, one shared geometry, "
            f"1% lognormal noise; a float64 `.npy` memory-mapped by `brdf-fit fit-batch "
            f"--values ... --out-dir DIR [--processes P]`; blocks of {bs}. Each run is a fresh "
            f"process tree with the compilation cache filled by a warm-up of one block "
            f"({w_wall:.1f} s cold: importing JAX and compiling). CPU: the processes' user + "
            "system seconds. Every run's parameter maps are compared with the first run's.", "",
            "| processes | wall s | CPU s | fits/s | speed-up | efficiency | converged | "
            "maps equal to P=1 | load (start, end) |",
            "|---:|---:|---:|---:|---:|---:|---:|---|---|"]
        for r in rows:
            lines.append(
                f"| {r['processes']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | "
                f"{r['fits_per_s']:.0f} | {r['speedup']:.2f} | {r['efficiency']:.2f} | "
                f"{100 * r['converged']:.2f}% | {'yes' if r['equal_to_first'] else 'NO'} | "
                f"{r['loadavg_start'][0]:.2f}, {r['loadavg_end'][0]:.2f} |")
        lines += [
            "", "Speed-up is against the first row; efficiency is speed-up over the process "
            f"ratio. This machine has {info['cores']} cores: past that, processes share them "
            "(and one process already runs some of XLA's work on a second thread), so the "
            "speed-up is bounded by the cores, not by the method.", "",
            f"**Projection** for a 4K SVBRDF ({TEXELS_4K:.3g} texels, this model and sample "
            f"count) on a cluster of {cluster['nodes']} nodes x {cluster['processes_per_node']} "
            f"processes ({procs} processes, one per core, blocks on a shared filesystem): "
            f"{TEXELS_4K:.3g} / ({per_proc:.0f} fits per CPU second x {procs}) + "
            f"{startup:.0f} s start-up = **{proj:.0f} s**, assuming each core fits at the "
            "rate per CPU second of the first run here, perfect scaling (the blocks are "
            "independent: no communication but the manifest and two barriers) and one "
            "compilation per process. Not measured on a cluster.", ""]
        (out / "distributed.md").write_text("\n".join(lines))
        print("\n".join(lines))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
