"""A whole MERL file fitted by brdf_fit and by Mitsuba 3 + Adam, in one run (issue 44).

The file is made by Mitsuba 3 itself: its ``roughconductor`` (GGX, alpha 0.12, ``material =
"Cu"``, variant ``llvm_ad_rgb``) evaluated with ``BSDF.eval`` at every MERL bin centre and
written as a MERL ``.binary`` (1,096,216 valid bins per channel). Both tools then fit Mitsuba's
roughconductor (here: the registry entry ``mitsuba-roughconductor``, alpha and RGB eta, k) from
the same generic start, alpha 0.3, eta 1, k 1:

* **brdf_fit**: ``brdf-fit fit FILE --model mitsuba-roughconductor --init alpha=0.3 --init
  eta=1,1,1 --init k=1,1,1 --json`` as a fresh process, twice: with an empty cache folder
  (compilation included) and with the caches the first run filled. Reported: the whole
  command's wall time, the fit's own time (``seconds`` of its JSON), steps, alpha, the
  relative RMS of the fitted model against the data, and the process's peak resident memory.
* **Mitsuba 3 + Adam**: a fresh process that reads the same file (brdf_fit's MERL reader),
  evaluates ``bsdf.eval`` on all bins in one call per iteration and optimises log alpha,
  log eta, log k with ``mi.ad.Adam(lr=0.05)`` on the mean squared log residual
  ``log1p(f cos) - log1p(y cos)`` (the metric brdf_fit fits by default); the time at which
  alpha first comes within 1e-3 of 0.12, the time from which it stays there, and the relative
  RMS then. ``ADAM_ITERATIONS`` iterations in all.

Timings are wall-clock on this machine in one run (the ratio is what to read; the machine's
load moves both).

    DRJIT_LIBLLVM_PATH=/tmp/llvm19/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1 \\
        python benchmarks/bench_merl_fit.py      # writes results/merl_fit.{json,md}

Mitsuba's LLVM variant needs a libLLVM it can load (19 works; Debian's 15 aborts the process):
``apt-get download libllvm19 && dpkg-deb -x libllvm19_*.deb /tmp/llvm19`` (as for
``bench_eval.py``).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from bench_latency import _cpu  # noqa: E402  (the CPU's model name)

RESULTS = os.path.join(HERE, "results")
ALPHA = 0.12
ALPHA_TOL = 1e-3
ADAM_ITERATIONS = 150
ADAM_LR = 0.05
START = {"alpha": 0.3, "eta": 1.0, "k": 1.0}
#: subset sizes of the cost-against-work rows (``--max-samples``; the last is the whole file)
SCALING_SAMPLES = (1000, 10_000, 100_000, 300_000, 1_096_216)
VARIANT = "llvm_ad_rgb"

#: a child's own peak resident memory in KiB (VmHWM: ru_maxrss would carry the parent's
#: high-water mark across exec on Linux)
PEAK = ("def _peak():\n"
        "    for line in open('/proc/self/status'):\n"
        "        if line.startswith('VmHWM:'):\n"
        "            return int(line.split()[1])\n")
#: brdf_fit's command run inside a process that reports its own peak memory
OURS = PEAK + ("import sys\n"
               "from brdf_fit.cli import main\n"
               "status = main(sys.argv[1:])\n"
               "print('PEAK_KIB', _peak(), file=sys.stderr)\n"
               "sys.exit(status)\n")


#: the child process that renders MERL files with Mitsuba (argv: folder, JSON list of
#: [name, BSDF dict]): each BSDF's ``eval`` at every bin centre, written as ``folder/name.binary``
#: (bench_database.py renders its ten files with it too)
RENDER = f"""
import json, sys
import numpy as np
import mitsuba as mi
import drjit as dr
from brdf_fit.io.merl import write_merl
mi.set_variant({VARIANT!r})
folder, materials = sys.argv[1], json.loads(sys.argv[2])
for name, d in materials:
    bsdf = mi.load_dict(d)

    def f(wi, wo):
        si = dr.zeros(mi.SurfaceInteraction3f, wi.shape[0])
        si.wi = mi.Vector3f(wo[:, 0], wo[:, 1], wo[:, 2])
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        v = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(wi[:, 0], wi[:, 1], wi[:, 2]))
        return np.stack([np.asarray(v[c]) for c in range(3)], -1) / wi[:, 2:3]

    write_merl(f"{{folder}}/{{name}}.binary", f, chunk=1 << 21)
"""
#: the material of this benchmark's file
MATERIAL = ("mitsuba_cu_ggx_0.12", {"type": "roughconductor", "distribution": "ggx",
                                    "alpha": ALPHA, "material": "Cu"})


def render(folder: str, materials) -> None:
    """Write ``folder/NAME.binary`` for each ``(NAME, Mitsuba BSDF dict)`` (:data:`RENDER`)."""
    subprocess.run([sys.executable, "-c", RENDER, folder, json.dumps(list(materials))],
                   check=True)


#: the child that fits with Mitsuba + Adam (argv: MERL path); prints one JSON line
ADAM = PEAK + f"""
import json, sys, time
t_start = time.perf_counter()
import numpy as np
import mitsuba as mi
import drjit as dr
from brdf_fit.io.merl import read_merl
mi.set_variant({VARIANT!r})
d = read_merl(sys.argv[1])
wi, wo, y = d.wi, d.wo, d.value
bsdf = mi.load_dict({{"type": "roughconductor", "distribution": "ggx", "alpha": {START['alpha']},
                      "eta": {{"type": "rgb", "value": [{START['eta']}] * 3}},
                      "k": {{"type": "rgb", "value": [{START['k']}] * 3}}}})
params = mi.traverse(bsdf)
si = dr.zeros(mi.SurfaceInteraction3f, wi.shape[0])
si.wi = mi.Vector3f(wo[:, 0], wo[:, 1], wo[:, 2])
si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
wl = mi.Vector3f(wi[:, 0], wi[:, 1], wi[:, 2])
cos = mi.Float(wi[:, 2])
target = [mi.Float(np.log1p(y[:, c] * wi[:, 2])) for c in range(3)]
ctx = mi.BSDFContext()
opt = mi.ad.Adam(lr={ADAM_LR})
opt["alpha"] = dr.log(mi.Float({START['alpha']}))
opt["eta"] = dr.log(mi.Color3f({START['eta']}))
opt["k"] = dr.log(mi.Color3f({START['k']}))
t0 = time.perf_counter()
trace = []
for it in range({ADAM_ITERATIONS}):
    params["alpha.value"] = dr.exp(opt["alpha"])
    params["eta.value"] = dr.exp(opt["eta"])
    params["k.value"] = dr.exp(opt["k"])
    params.update()
    v = bsdf.eval(ctx, si, wl)  # f cos
    loss = 0
    for c in range(3):
        r = dr.log(1.0 + v[c]) - target[c]  # Dr.Jit has no log1p
        loss = loss + dr.mean(r * r)
    dr.backward(loss)
    opt.step()
    a = float(dr.exp(opt["alpha"])[0])
    trace.append((time.perf_counter() - t0, a, float(loss[0])))
# relative RMS of the final parameters against the data
params["alpha.value"] = dr.exp(opt["alpha"]); params["eta.value"] = dr.exp(opt["eta"])
params["k.value"] = dr.exp(opt["k"]); params.update()
v = bsdf.eval(ctx, si, wl)
f = np.stack([np.asarray(v[c]) for c in range(3)], -1) / wi[:, 2:3]
rel = float(np.sqrt(np.mean(((f - y) * wi[:, 2:3]) ** 2) / np.mean((y * wi[:, 2:3]) ** 2)))
print(json.dumps({{"trace": trace, "rel_rms_final": rel, "setup_s": t0 - t_start,
                  "maxrss_kib": _peak()}}))
"""

def _rel_rms(params: dict, path: str) -> float:
    """Relative cosine-weighted RMS of the fitted mitsuba-roughconductor against the file."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from brdf_fit import registry
    from brdf_fit.io.merl import read_merl
    from brdf_fit.models._base import evaluate

    d = read_merl(path)
    m = registry.get("mitsuba-roughconductor").build(
        **{k: np.asarray(v) for k, v in params.items()})
    f = np.asarray(evaluate(m, d.wi, d.wo))
    c = d.wi[:, 2:3]
    return float(np.sqrt(np.mean(((f - d.value) * c) ** 2) / np.mean((d.value * c) ** 2)))


def run_ours(path: str, cache: str, max_samples: int | None = None) -> dict:
    args = ["fit", path, "--model", "mitsuba-roughconductor", "--init",
            f"alpha={START['alpha']}", "--init", "eta={0},{0},{0}".format(START["eta"]),
            "--init", "k={0},{0},{0}".format(START["k"]), "--json", "--quiet"]
    if max_samples is not None:
        args += ["--max-samples", str(max_samples)]
    env = {**os.environ, "BRDF_FIT_CACHE_DIR": cache}
    t = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", OURS, *args], capture_output=True, text=True,
                         env=env, check=False)
    wall = time.perf_counter() - t
    if out.returncode not in (0, 1):
        raise RuntimeError(out.stderr[-3000:])
    doc = json.loads(out.stdout)
    return {"wall_s": wall, "fit_s": doc["seconds"], "steps": doc["steps"],
            "n_samples": doc["n_samples"],
            "converged": doc["converged"], "alpha": doc["params"]["alpha"],
            "params": doc["params"],
            "maxrss_mib": int(out.stderr.split("PEAK_KIB")[1].split()[0]) / 1024.0}


def run_adam(path: str) -> dict:
    t = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", ADAM, path], capture_output=True, text=True,
                         check=True)
    wall = time.perf_counter() - t
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    trace = doc["trace"]
    first = next((t for t, a, _ in trace if abs(a - ALPHA) <= ALPHA_TOL), None)
    stays = None
    for i, (t_i, _, _) in enumerate(trace):
        if all(abs(a - ALPHA) <= ALPHA_TOL for _, a, _ in trace[i:]):
            stays = t_i
            break
    return {"wall_s": wall, "setup_s": doc["setup_s"], "first_within_s": first,
            "stays_within_s": stays, "iterations": len(trace), "alpha_final": trace[-1][1],
            "rel_rms_final": doc["rel_rms_final"], "maxrss_mib": doc["maxrss_kib"] / 1024.0}


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        render(tmp, [MATERIAL])
        path = os.path.join(tmp, MATERIAL[0] + ".binary")
        cache = os.path.join(tmp, "cache")
        cold = run_ours(path, cache)
        warm = run_ours(path, cache)
        adam = run_adam(path)
        # cost against work: the same fit of seeded random subsets (caches filled by a first
        # run of each size, so the figures are the fit's, not its compilation's)
        scaling = []
        for n in SCALING_SAMPLES:
            run_ours(path, cache, n)
            scaling.append(run_ours(path, cache, n))
        cold["rel_rms"] = warm["rel_rms"] = _rel_rms(warm["params"], path)
    doc = {"machine": _cpu(), "cpus": os.cpu_count(),
           "date": time.strftime("%Y-%m-%d"), "brdf_fit_cold": cold, "brdf_fit_warm": warm,
           "mitsuba_adam": adam, "scaling": scaling,
           "command": "python benchmarks/bench_merl_fit.py"}
    os.makedirs(RESULTS, exist_ok=True)
    with open(os.path.join(RESULTS, "merl_fit.json"), "w") as fh:
        json.dump(doc, fh, indent=2)

    def s(x):
        return "-" if x is None else f"{x:.2f} s"

    lines = [
        "# A whole MERL file: brdf_fit against Mitsuba 3 + Adam",
        "",
        f"`{doc['command']}` on {doc['cpus']} cores ({doc['machine']}), {doc['date']}. The file: "
        "Mitsuba 3's roughconductor (GGX, alpha 0.12, Cu, llvm_ad_rgb) at every MERL bin centre "
        "(1,096,216 valid bins x RGB); both fit it from alpha 0.3, eta 1, k 1.",
        "",
        "| tool | alpha within 1e-3 | converged / stays within | steps | alpha | rel. RMS | "
        "whole command | peak memory |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for label, r in (("brdf_fit, empty caches", cold), ("brdf_fit, caches filled", warm)):
        lines.append(
            f"| {label} | - | {r['fit_s']:.2f} s (fit) | {r['steps']} | {r['alpha']:.6f} | "
            f"{r['rel_rms']:.2e} | {r['wall_s']:.2f} s | {r['maxrss_mib']:.0f} MiB |")
    lines.append(
        f"| Mitsuba 3 + Adam (lr {ADAM_LR}) | {s(adam['first_within_s'])} | "
        f"{s(adam['stays_within_s'])} | {adam['iterations']} | {adam['alpha_final']:.6f} | "
        f"{adam['rel_rms_final']:.2e} | {adam['wall_s']:.2f} s (setup "
        f"{adam['setup_s']:.2f} s) | {adam['maxrss_mib']:.0f} MiB |")
    lines += ["", "brdf_fit's fit time is its JSON's `seconds` (reading the file excluded, "
              "compilation included); Mitsuba's times count from its first iteration (setup: "
              "import, reading the file, building the BSDF)."]
    lines += ["", "## Cost against work", "",
              "The same fit of seeded random subsets (`--max-samples N`), caches filled; "
              "subsets below 131,072 residuals (43,690 samples x RGB) take the dense solver.",
              "", "| samples | fit time | steps | peak memory |", "|---|---|---|---|"]
    for r in scaling:
        lines.append(f"| {r['n_samples']:,} | {r['fit_s']:.2f} s | {r['steps']} | "
                     f"{r['maxrss_mib']:.0f} MiB |")
    with open(os.path.join(RESULTS, "merl_fit.md"), "w") as fh:
        fh.write("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
