"""Do the standard errors cover the truth? Coverage of the 95% intervals of ``fit_batch``'s
estimates over noise draws, per instrument density, model and sandwich estimator (issue 40).

    python benchmarks/bench_coverage.py [--draws 200]   # writes results/coverage.{json,md}

For each instrument (``sparse``: 24 random direction pairs; ``dense``: 300; directions at least
0.05 above the horizon, seeded) and model (``ggx``, ``beckmann`` and the layered ``ggx-plastic``,
a Lambert base under a GGX coat, each at a coloured truth), ``--draws`` copies of the model's
values with 2% multiplicative log-normal noise are fitted at once by ``fit_batch`` (one batch
sharing the geometry, the default metric ``log``, no sigma: the sandwich estimator), and for
every fitted entry ``z = (estimate - truth) / stderr``. Reported: the fraction of draws with
``|z| <= 1.96`` (the 95% interval covers the truth; honest: 0.95, and with 200 draws the
binomial standard deviation of that fraction is 0.015) and the rms of ``z`` (honest: 1).

Each sandwich estimator runs in a child process of its own
(``brdf_fit.fitting.solvers.SANDWICH`` is read when a program is traced): ``HC3``, the
default, and ``HC1``, the estimator before issue 40, for comparison. What HC3 costs: each child
also times ``fit_batch`` on :data:`TIMED_PROBLEMS` GGX problems of 300 samples (one shared
geometry, 1% noise; best of :data:`TIMED_REPEATS` after a first call that compiles): HC3's
leverages need one more pass over the data after the solve, HC1 reads the solver's carried
normal equations.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")
INSTRUMENTS = {"sparse": 24, "dense": 300}
TRUTHS = {
    "ggx": {"alpha": 0.23, "f0": [0.9, 0.6, 0.3]},
    "beckmann": {"alpha": 0.3, "f0": [0.3, 0.6, 0.9]},
    "ggx-plastic": {"rho_d": [0.5, 0.2, 0.1], "alpha": 0.2, "f0": 0.04},
}
NOISE = 0.02
ESTIMATORS = ("HC3", "HC1")
TIMED_PROBLEMS = 10_000
TIMED_REPEATS = 5
Z95 = 1.959964


def _directions(rng, n, lo=0.05):
    """``n`` unit vectors uniform on the hemisphere above ``z = lo``."""
    z = rng.uniform(lo, 1.0, n)
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    s = np.sqrt(1.0 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], -1)


def run_estimator(estimator: str, draws: int) -> list[dict]:
    """Every (instrument, model) row under one sandwich estimator, in this process."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from brdf_fit import registry
    from brdf_fit.fitting import solvers
    from brdf_fit.fitting.batch import fit_batch

    solvers.SANDWICH = estimator
    rows = []
    for inst, n in INSTRUMENTS.items():
        rng = np.random.default_rng(11)
        wi, wo = _directions(rng, n), _directions(rng, n)
        for name, truth in TRUTHS.items():
            entry = registry.get(name)
            f = np.asarray(entry.build(**{k: np.asarray(v) for k, v in truth.items()})
                           .eval(wi, wo))
            noisy = f[None] * np.exp(NOISE * np.random.default_rng(5).standard_normal(
                (draws, *f.shape)))
            t = time.perf_counter()
            r = fit_batch(wi, wo, noisy, name)
            seconds = time.perf_counter() - t
            ok = np.asarray(r.converged, bool)
            for p, value in truth.items():
                est = np.asarray(r.params[p]).reshape(draws, -1)[ok]
                se = np.asarray(r.stderr[p]).reshape(draws, -1)[ok]
                z = (est - np.ravel(value)[None]) / se
                for j in range(z.shape[1]):
                    zj = z[:, j][np.isfinite(z[:, j])]
                    label = p if z.shape[1] == 1 else f"{p}[{'RGB'[j]}]"
                    rows.append({"estimator": estimator, "instrument": inst, "samples": n,
                                 "model": name, "entry": label, "draws": int(zj.size),
                                 "converged": int(ok.sum()),
                                 "coverage95": float(np.mean(np.abs(zj) <= Z95)),
                                 "rms_z": float(np.sqrt(np.mean(zj**2))),
                                 "fit_seconds": round(seconds, 3)})
    return rows


def time_estimator(estimator: str) -> dict:
    """Best wall time of ``fit_batch`` on :data:`TIMED_PROBLEMS` GGX problems (this process's
    estimator, set by :func:`run_estimator`)."""
    from brdf_fit import registry
    from brdf_fit.fitting.batch import fit_batch

    rng = np.random.default_rng(0)
    wi, wo = _directions(rng, 300), _directions(rng, 300)
    entry = registry.get("ggx")
    alphas, f0s = rng.uniform(0.1, 0.5, 50), rng.uniform(0.2, 0.9, (50, 3))
    f = np.stack([np.asarray(entry.build(alpha=a, f0=c).eval(wi, wo))
                  for a, c in zip(alphas, f0s, strict=True)])
    f = np.tile(f, (TIMED_PROBLEMS // 50, 1, 1)) * np.exp(
        0.01 * rng.standard_normal((TIMED_PROBLEMS, 300, 3)))
    fit_batch(wi, wo, f, "ggx")  # compiles
    times = []
    for _ in range(TIMED_REPEATS):
        t = time.perf_counter()
        fit_batch(wi, wo, f, "ggx")
        times.append(time.perf_counter() - t)
    return {"estimator": estimator, "problems": TIMED_PROBLEMS, "best_s": min(times),
            "times_s": times}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--draws", type=int, default=200)
    ap.add_argument("--estimator", choices=ESTIMATORS, help=argparse.SUPPRESS)  # the child
    ap.add_argument("--out", default=RESULTS)
    args = ap.parse_args()
    if args.estimator:
        rows = run_estimator(args.estimator, args.draws)
        print(json.dumps({"rows": rows, "timing": time_estimator(args.estimator)}))
        return
    rows, timing = [], {}
    for est in ESTIMATORS:
        out = subprocess.run([sys.executable, __file__, "--estimator", est, "--draws",
                              str(args.draws)], capture_output=True, text=True, check=True)
        doc = json.loads(out.stdout.strip().splitlines()[-1])
        rows += doc["rows"]
        timing[est] = doc["timing"]
    os.makedirs(args.out, exist_ok=True)
    meta = {"command": f"python benchmarks/bench_coverage.py --draws {args.draws}",
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "machine": f"{platform.machine()}, {os.cpu_count()} cores", "noise": NOISE,
            "draws": args.draws}
    with open(os.path.join(args.out, "coverage.json"), "w") as fh:
        json.dump({"meta": meta, "rows": rows, "timing": timing}, fh, indent=1)
    lines = ["# Coverage of the standard errors: fit_batch, 2% noise, no sigma", "",
             f"`{meta['command']}` on {meta['machine']}, {meta['date']}. Each row: "
             f"{args.draws} noise draws of one material on one instrument, fitted at once; "
             "coverage = fraction of draws whose 95% interval (estimate +- 1.96 stderr) holds "
             "the truth (honest: 0.95, +-0.015 from the draws alone); rms z = rms of "
             "(estimate - truth) / stderr (honest: 1). HC3 is the default sandwich estimator, "
             "HC1 the one before issue 40.", "",
             "| instrument | model | entry | HC3 coverage | HC3 rms z | HC1 coverage | HC1 rms z |",
             "|---|---|---|---:|---:|---:|---:|"]
    key = {(r["estimator"], r["instrument"], r["model"], r["entry"]): r for r in rows}
    for r in rows:
        if r["estimator"] != "HC3":
            continue
        h1 = key[("HC1", r["instrument"], r["model"], r["entry"])]
        lines.append(f"| {r['instrument']} ({r['samples']}) | {r['model']} | {r['entry']} | "
                     f"{r['coverage95']:.3f} | {r['rms_z']:.2f} | {h1['coverage95']:.3f} | "
                     f"{h1['rms_z']:.2f} |")
    t3, t1 = timing["HC3"]["best_s"], timing["HC1"]["best_s"]
    lines += ["", f"What HC3 costs: `fit_batch` on {TIMED_PROBLEMS:,} GGX problems of 300 "
              f"samples, best of {TIMED_REPEATS}: {t3:.2f} s with HC3, {t1:.2f} s with HC1 "
              f"({t3 / t1:.2f}x; the leverages need one more pass over the data)."]
    with open(os.path.join(args.out, "coverage.md"), "w") as fh:
        fh.write("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
