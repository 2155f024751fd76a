"""A database run: 10 MERL files fitted to 5 models, one process and two (issue 44).

The files are made by Mitsuba 3 (``llvm_ad_rgb``, ``BSDF.eval`` at every MERL bin centre):
five conductors (``roughconductor``, GGX and Beckmann, alpha 0.05-0.4, tabulated metals) and
five plastics (``roughplastic``, GGX, alpha 0.08-0.3, coloured diffuse), so that some models
represent a file and others do not. Each is fitted to ``ggx``, ``beckmann``, ``ggx-plastic``,
``ward`` and ``lambert`` with

    brdf-fit fit FOLDER --model ggx,beckmann,ggx-plastic,ward,lambert --table T.csv

in a fresh process with empty caches (compilation included), then the same with
``--processes 2`` into another table; the two tables are compared (every column but the time).
Reported: each run's wall time, the pairs that converged, and the table's relative RMS error per
material and model.

    DRJIT_LIBLLVM_PATH=/tmp/llvm19/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1 \\
        python benchmarks/bench_database.py      # writes results/database.{json,md,png}

(Mitsuba's LLVM variant needs a libLLVM it can load: see ``bench_merl_fit.py``.)
"""

from __future__ import annotations

import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time

from bench_merl_fit import render  # Mitsuba's BSDFs at every MERL bin centre

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")
MODELS = ("ggx", "beckmann", "ggx-plastic", "ward", "lambert")
#: the materials: (name, Mitsuba BSDF dict)
MATERIALS = [
    ("cu_ggx_005", {"type": "roughconductor", "distribution": "ggx", "alpha": 0.05,
                    "material": "Cu"}),
    ("au_ggx_012", {"type": "roughconductor", "distribution": "ggx", "alpha": 0.12,
                    "material": "Au"}),
    ("al_ggx_025", {"type": "roughconductor", "distribution": "ggx", "alpha": 0.25,
                    "material": "Al"}),
    ("ag_beckmann_01", {"type": "roughconductor", "distribution": "beckmann", "alpha": 0.1,
                        "material": "Ag"}),
    ("cr_ggx_04", {"type": "roughconductor", "distribution": "ggx", "alpha": 0.4,
                   "material": "Cr"}),
    ("red_plastic_008", {"type": "roughplastic", "distribution": "ggx", "alpha": 0.08,
                         "diffuse_reflectance": {"type": "rgb", "value": [0.6, 0.05, 0.04]}}),
    ("blue_plastic_015", {"type": "roughplastic", "distribution": "ggx", "alpha": 0.15,
                          "diffuse_reflectance": {"type": "rgb", "value": [0.05, 0.1, 0.5]}}),
    ("white_plastic_03", {"type": "roughplastic", "distribution": "ggx", "alpha": 0.3,
                          "diffuse_reflectance": {"type": "rgb", "value": [0.8, 0.8, 0.8]}}),
    ("green_plastic_02", {"type": "roughplastic", "distribution": "ggx", "alpha": 0.2,
                          "diffuse_reflectance": {"type": "rgb", "value": [0.1, 0.4, 0.1]}}),
    ("grey_plastic_012", {"type": "roughplastic", "distribution": "ggx", "alpha": 0.12,
                          "diffuse_reflectance": {"type": "rgb", "value": [0.2, 0.2, 0.2]}}),
]

def run(folder: str, table: str, cache: str, processes: int | None) -> dict:
    cmd = [sys.executable, "-m", "brdf_fit.cli", "fit", folder, "--model", ",".join(MODELS),
           "--table", table, "--json", "--quiet"]
    if processes:
        cmd += ["--processes", str(processes)]
    env = {**os.environ, "BRDF_FIT_CACHE_DIR": cache}
    t = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    wall = time.perf_counter() - t
    if out.returncode not in (0, 1):
        raise RuntimeError(out.stderr[-3000:])
    doc = json.loads(out.stdout)
    return {"wall_s": wall, "exit": out.returncode, "doc": doc}


def main() -> None:
    tmp = tempfile.mkdtemp()
    try:
        data = os.path.join(tmp, "merl")
        os.makedirs(data)
        render(data, MATERIALS)
        one = run(data, os.path.join(tmp, "one.csv"), os.path.join(tmp, "cache1"), None)
        two = run(data, os.path.join(tmp, "two.csv"), os.path.join(tmp, "cache2"), 2)
        if os.path.exists(os.path.join(tmp, "one.png")):
            os.makedirs(RESULTS, exist_ok=True)
            shutil.copy(os.path.join(tmp, "one.png"), os.path.join(RESULTS, "database.png"))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    def strip(rows):
        return [{k: v for k, v in r.items() if k not in ("seconds", "file")} for r in rows]

    rows = one["doc"]["rows"]
    same = strip(rows) == strip(two["doc"]["rows"])
    doc = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
           "date": time.strftime("%Y-%m-%d"), "models": MODELS,
           "materials": [m for m, _ in MATERIALS],
           "one_process_s": one["wall_s"], "two_processes_s": two["wall_s"],
           "tables_equal": same, "rows": rows,
           "command": "python benchmarks/bench_database.py"}
    os.makedirs(RESULTS, exist_ok=True)
    with open(os.path.join(RESULTS, "database.json"), "w") as fh:
        json.dump(doc, fh, indent=1)
    conv = sum(r["converged"] for r in rows)
    lines = [
        "# A database run: 10 MERL files x 5 models",
        "",
        f"`{doc['command']}` on {doc['cpus']} cores ({doc['machine']}), {doc['date']}: 10 MERL "
        "files made by Mitsuba 3 (5 rough conductors, 5 rough plastics), each fitted to "
        f"{', '.join(MODELS)} by one `brdf-fit fit FOLDER --model ... --table T.csv` "
        "(a fresh process, empty caches).",
        "",
        f"- one process: **{one['wall_s']:.1f} s** for {len(rows)} pairs ({conv} converged)",
        f"- `--processes 2`: {two['wall_s']:.1f} s; the tables are "
        + ("identical (every column but the time)" if same else "**different**"),
        "",
        "Relative RMS radiance error (`*`: did not converge):",
        "",
        "| material | " + " | ".join(MODELS) + " |",
        "|---|" + "---|" * len(MODELS),
    ]
    by = {(r["material"], r["model"]): r for r in rows}
    for m, _ in MATERIALS:
        cells = []
        for k in MODELS:
            r = by.get((m, k))
            cells.append("-" if r is None else
                         f"{r['errors']['rel_rms']:.3g}{'' if r['converged'] else '*'}")
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    lines += ["", "![each model's error over the materials](database.png)"]
    with open(os.path.join(RESULTS, "database.md"), "w") as fh:
        fh.write("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
