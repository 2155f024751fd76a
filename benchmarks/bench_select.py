"""Wall time of `brdf-fit select` as a user meets it (issue 18's speed targets), each command in
a fresh process: cold (an empty compilation cache) and warm (the cache the cold run filled).

* one data file of about 1000 samples (a GGX plastic on a four-axis plan, 1% noise) over the
  default candidates; target <= 60 s cold, <= 20 s warm on 2 cores;
* a scene of 20 materials (the embedded example scene's 9 plus 11 registry-model materials);
  target <= 3 minutes warm.

    .venv/bin/python benchmarks/bench_select.py          # writes benchmarks/results/select.md

The figures are absolute seconds on this machine (the targets are absolute); the machine's load
average at the start of each run is recorded beside it.
"""

from __future__ import annotations

import json
import os
import pathlib
import platform
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
BIN = pathlib.Path(sys.executable).parent / "brdf-fit"
OUT = ROOT / "benchmarks" / "results" / "select.md"

RECIPE = {
    "name": "plastic-1k", "model": "ggx-plastic", "seed": 7, "params": {"alpha": 0.2},
    "plan": {"name": "four_axis", "args": {
        "theta_i_deg": [0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0],
        "theta_o_deg": [0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0],
        "phi_o_deg": [22.5 * k for k in range(16)],
        "max_zenith_deg": 80.0, "min_separation_deg": 5.0}},
    "noise": [{"type": "lognormal", "args": {"sigma": 0.01}}],
}

#: the 11 registry-model materials added to the example scene's 9
EXTRA = [
    ("ggx", {"alpha": a, "f0": [0.9, 0.6, 0.5]}) for a in (0.05, 0.12, 0.3, 0.5)
] + [
    ("ggx-plastic", {"rho_d": [0.2 + 0.1 * k, 0.3, 0.4 - 0.1 * k], "alpha": 0.1 + 0.1 * k,
                     "f0": 0.04}) for k in range(3)
] + [
    ("lambert", {"rho": [0.8, 0.7, 0.5]}),
    ("oren-nayar", {"rho": [0.6, 0.5, 0.4], "sigma": 0.3}),
    ("ggx-conductor", {"alpha": 0.25}),
    ("beckmann", {"alpha": 0.2, "f0": [0.05, 0.05, 0.05]}),
]


def toml_value(v) -> str:
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return repr(float(v))


def run(argv, env) -> tuple[float, dict]:
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    p = subprocess.run(argv, env=env, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if p.returncode not in (0, 1):
        raise SystemExit(f"{' '.join(map(str, argv))} failed:\n{p.stderr}")
    return dt, {"load": load, "doc": json.loads(p.stdout)}


def main() -> None:
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="bench_select_"))
    env = dict(os.environ, BRDF_FIT_CACHE_DIR=str(tmp / "cache"))
    (tmp / "plastic1k.json").write_text(json.dumps(RECIPE))
    subprocess.run([BIN, "synth", tmp / "plastic1k.json", "-o", tmp / "plastic1k.csv"],
                   check=True, capture_output=True)
    from brdf_fit.selection.scene import EXAMPLE_SCENE

    scene_dir = tmp / "scene"
    shutil.copytree(EXAMPLE_SCENE.parent, scene_dir)
    text = EXAMPLE_SCENE.read_text()
    for i, (model, params) in enumerate(EXTRA):
        body = ", ".join(f"{k} = {toml_value(v)}" for k, v in params.items())
        text += f'\n[[material]]\nname = "extra-{i}-{model}"\nmodel = "{model}"\n'
        text += f"params = {{ {body} }}\n"
    (scene_dir / "scene20.toml").write_text(text)
    rows = []
    for label, argv in [
        ("select, 1000-sample file, default candidates",
         [BIN, "select", tmp / "plastic1k.csv", "--quiet", "--json"]),
        ("select --scene, 20 materials, default candidates",
         [BIN, "select", "--scene", scene_dir / "scene20.toml", "--quiet", "--json"]),
    ]:
        shutil.rmtree(tmp / "cache", ignore_errors=True)
        cold, c = run(argv, env)
        warm, w = run(argv, env)
        doc = w["doc"]
        n = (doc.get("n_samples") or sum(m["n_samples"] for m in doc["materials"]))
        what = (f"choice {doc['choice']}" if "choice" in doc else
                f"{len(doc['materials'])} materials, set {', '.join(doc['model_set'])}")
        rows.append((label, cold, c["load"], warm, w["load"], n, what))
        print(f"{label}: cold {cold:.1f} s, warm {warm:.1f} s ({what})", flush=True)
    shutil.rmtree(tmp, ignore_errors=True)
    lines = [
        "# `brdf-fit select`: wall time from a fresh process",
        "",
        "Command: `.venv/bin/python benchmarks/bench_select.py` "
        f"({time.strftime('%Y-%m-%d')}, {platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}). Cold: an empty compilation cache "
        "(`BRDF_FIT_CACHE_DIR` in a temporary folder); warm: the same command again.",
        "",
        "| command | cold [s] | load | warm [s] | load | samples | outcome |",
        "|---|---|---|---|---|---|---|",
    ]
    for label, cold, lc, warm, lw, n, what in rows:
        lines.append(f"| {label} | {cold:.1f} | {lc:.2f} | {warm:.1f} | {lw:.2f} | {n} | "
                     f"{what} |")
    lines += ["", "Targets (issue 18): the file <= 60 s cold and <= 20 s warm; the 20-material "
              "scene <= 180 s warm. `load` is the 1-minute load average when the command "
              "started (2 cores: 2.0 is a busy machine).", ""]
    OUT.write_text("\n".join(lines))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
