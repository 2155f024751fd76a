"""Blender materials measured in Cycles, fitted for Blender, exported and rendered again: the
figures of the Blender target's row in docs/guide/renderers.md (issue 42).

    python benchmarks/bench_blender_roundtrip.py [--out DIR] [--shader-tables PATH]

Needs a Blender Python (``make blender``; :func:`brdf_fit.convert.blender.find_blender_python`).
For each material (a Principled BSDF made in Blender 4.5 by the export script, every other
input at Blender's default: a plastic, a metal, a coated dielectric, a sheen, a brushed metal):

1. Cycles renders it at a four-axis gonioreflectometer plan (``data_synth.plans.four_axis``:
   theta_i 0-80 deg by 20, theta_o 0-80 by 10, phi_o by 30 deg; direct light only, the
   harness :mod:`brdf_fit.convert.cycles_gonio`): noise-free data (float32 rendering);
2. ``brdf_fit.selection.select(data, target="blender")`` chooses an entry and fits it (its
   time is the figure "select");
3. the choice is exported (:func:`brdf_fit.convert.blender.to_blender`), run in Blender and
   rendered by Cycles at the same directions: the cosine-weighted relative RMS of that render
   against the data, and the fitted base colour and roughness against what was set.

With ``--shader-tables`` (Cycles' ``src/scene/shader.tables``, e.g. from a Cycles checkout of
the Blender 4.5 release branch) it also compares the shipped tables with Cycles' printed ones
(:func:`brdf_fit.tables.cycles.compare`). Writes ``blender_roundtrip.md`` and ``.json``.
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

from brdf_fit.convert import blender as cb  # noqa: E402
from brdf_fit.data import GonioData  # noqa: E402
from brdf_fit.selection import select  # noqa: E402
from data_synth.plans import four_axis  # noqa: E402

#: the materials (the Principled BSDF's inputs; Blender's defaults for the rest)
MATERIALS = {
    "red plastic": dict(base_color=[0.8, 0.05, 0.05], roughness=0.35, metallic=0.0, ior=1.5),
    "copper-like metal": dict(base_color=[0.95, 0.64, 0.54], roughness=0.25, metallic=1.0,
                              ior=1.5),
    "coated blue": dict(base_color=[0.1, 0.2, 0.6], roughness=0.5, metallic=0.0, ior=1.5,
                        coat_weight=1.0, coat_roughness=0.1, coat_ior=1.5),
    "coated metal": dict(base_color=[0.9, 0.55, 0.15], roughness=0.45, metallic=1.0, ior=1.5,
                         coat_weight=1.0, coat_roughness=0.05, coat_ior=1.5),
    "sheen fabric": dict(base_color=[0.5, 0.05, 0.2], roughness=0.7, metallic=0.0, ior=1.5,
                         sheen_weight=1.0, sheen_roughness=0.3),
    "brushed metal": dict(base_color=[0.8, 0.8, 0.8], roughness=0.3, metallic=1.0, ior=1.5,
                          anisotropic=0.8),
}


def _plan():
    return four_axis(theta_i_deg=tuple(range(0, 81, 20)), theta_o_deg=tuple(range(0, 81, 10)),
                     phi_o_deg=tuple(range(0, 360, 30)))


def run_material(label: str, params: dict, wi, wo) -> dict:
    name = label.replace(" ", "_")
    script = cb.blender_script([cb.material_spec(name, params)])
    t0 = time.perf_counter()
    measured = cb.measure_in_cycles(script, name, wi, wo)
    t_measure = time.perf_counter() - t0
    data = GonioData(wi=wi, wo=wo, value=measured["f_cos"] / wi[:, 2:3],
                     channels=("R", "G", "B"))
    t0 = time.perf_counter()
    sel = select(data, target="blender")
    t_select = time.perf_counter() - t0
    chosen = sel.candidate(sel.choice)
    export = cb.to_blender(sel.choice, chosen.params, name + "_fit")
    again = cb.measure_in_cycles(cb.blender_script([export.spec]), name + "_fit", wi, wo)
    d, e = measured["f_cos"], again["f_cos"]
    rel_rms = float(np.sqrt(np.sum((e - d) ** 2) / np.sum(d ** 2)))
    fitted = {k: np.asarray(v, np.float64).tolist() for k, v in chosen.params.items()}
    return {
        "material": label, "set": params, "pairs": int(len(wi)),
        "renders": measured["renders"], "measure_s": t_measure, "select_s": t_select,
        "candidates": [c.model for c in sel.candidates], "choice": sel.choice,
        "fitted": fitted, "error": float(chosen.error), "converged": bool(chosen.converged),
        "export_vs_data_rel_rms": rel_rms,
        "base_color_max_abs": float(np.max(np.abs(np.asarray(fitted["base_color"])
                                                  - np.asarray(params["base_color"])))),
        "roughness_abs": float(abs(fitted["roughness"] - params["roughness"])),
        "blender": measured["blender"],
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"))
    ap.add_argument("--shader-tables", default=None, metavar="PATH")
    ap.add_argument("--render-only", action="store_true",
                    help="re-write the .md from --out's blender_roundtrip.json")
    args = ap.parse_args(argv)
    if args.render_only:
        out = Path(args.out)
        info = json.loads((out / "blender_roundtrip.json").read_text(encoding="utf-8"))
        print(write_report(info, out))
        return 0
    plan = _plan()
    wi, wo = np.asarray(plan.wi), np.asarray(plan.wo)
    rows = []
    for label, params in MATERIALS.items():
        row = run_material(label, params, wi, wo)
        rows.append(row)
        print(f"{label}: {row['choice']} export vs data {row['export_vs_data_rel_rms']:.2e}, "
              f"select {row['select_s']:.1f} s", flush=True)
    tables = None
    if args.shader_tables:
        from brdf_fit.models._cycles import tables as _tables
        from brdf_fit.tables.cycles import compare

        rebuilt = ("ggx_E", "ggx_Eavg", "ggx_gen_schlick_ior_s")  # the sheen's is transcribed
        tables = compare(args.shader_tables, {k: _tables()[k] for k in rebuilt})
    info = {"command": "python " + " ".join(shlex.quote(a) for a in [sys.argv[0], *sys.argv[1:]]),
            "machine": machine_info(), "load": _loadavg(),
            "date": time.strftime("%Y-%m-%d"), "rows": rows, "tables": tables}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "blender_roundtrip.json").write_text(json.dumps(info, indent=1), encoding="utf-8")
    print(write_report(info, out))
    return 0


def write_report(info: dict, out: Path) -> str:
    """``blender_roundtrip.md`` from the run's JSON (``--render-only`` re-writes it)."""
    rows, tables, m = info["rows"], info["tables"], info["machine"]
    lines = [
        "# Blender materials through Cycles, select --target blender and back",
        "",
        f"`{info['command']}`; {m['cpu_model']}, {m['cpu_count']} cores; load "
        f"{info['load']}; {info['date']}; Blender {rows[0]['blender']}.",
        "",
        f"{rows[0]['pairs']} direction pairs (four-axis plan), rendered by Cycles (direct light, "
        "float32); each material fitted among the Blender entries and its export rendered again.",
        "",
        "| material (set in Blender) | chosen | base colour error (max abs) | roughness error | "
        "export in Cycles vs data (cos-weighted rel. RMS) | select (s) |",
        "| --- | --- | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        lines.append(f"| {r['material']} ({', '.join(f'{k} {v}' for k, v in r['set'].items())}) "
                     f"| `{r['choice']}` | {r['base_color_max_abs']:.1e} | "
                     f"{r['roughness_abs']:.1e} | {r['export_vs_data_rel_rms']:.1e} | "
                     f"{r['select_s']:.1f} |")
    if tables:
        lines += ["", "The shipped tables against Cycles' printed ones (`--shader-tables`):", "",
                  "| table | max abs difference | mean abs | where (node indices) |",
                  "| --- | ---: | ---: | --- |"]
        for k, v in tables.items():
            lines.append(f"| `{k}` | {v['max_abs']:.2e} | {v['mean_abs']:.2e} | {v['at']} |")
    text = "\n".join(lines) + "\n"
    (out / "blender_roundtrip.md").write_text(text, encoding="utf-8")
    return text


if __name__ == "__main__":
    sys.exit(main())
