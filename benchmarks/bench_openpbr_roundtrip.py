"""OpenPBR materials rendered by MaterialX's own GLSL, fitted for OpenPBR, exported and rendered
again: the figures of the OpenPBR target's row in docs/guide/renderers.md (issue 42).

    python benchmarks/bench_openpbr_roundtrip.py [--out DIR]

Needs the ``materialx`` extra and an EGL OpenGL context
(:mod:`brdf_fit.convert.materialx_render`). For each material (an ``open_pbr_surface`` node in a
MaterialX 1.39 document, every other input at the node's default: a plastic, a metal, a coated
dielectric, a coated metal, a fuzzy fabric, a brushed metal):

1. MaterialX's generated shader renders it at the four-axis plan of bench_blender_roundtrip
   (524 direction pairs; one directional light, no environment): noise-free float32 data
   (with fuzz, less the views along the normal, which MaterialX's fuzz does not define:
   :data:`NORMAL_VIEW`);
2. ``brdf_fit.selection.select(data, target="openpbr")`` chooses an entry and fits it (its
   time is the figure "select");
3. the choice is exported (:func:`brdf_fit.convert.materialx.to_materialx`), the document
   validated by MaterialX and rendered again at the same directions: the cosine-weighted
   relative RMS of that render against the data, and the fitted base colour and roughness
   against what was set.

Writes ``openpbr_roundtrip.md`` and ``.json``.
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
from bench_blender_roundtrip import _plan  # noqa: E402
from bench_eval import _loadavg, machine_info  # noqa: E402

from brdf_fit.convert import materialx as cx  # noqa: E402
from brdf_fit.convert import materialx_render as mr  # noqa: E402
from brdf_fit.data import GonioData  # noqa: E402
from brdf_fit.selection import select  # noqa: E402

#: the materials (the node's inputs; its defaults for the rest)
MATERIALS = {
    "red plastic": dict(base_color=[0.8, 0.05, 0.05], specular_roughness=0.35),
    "copper-like metal": dict(base_color=[0.95, 0.64, 0.54], base_metalness=1.0,
                              specular_roughness=0.25),
    "coated blue": dict(base_color=[0.1, 0.2, 0.6], specular_roughness=0.5, coat_weight=1.0,
                        coat_roughness=0.1, coat_ior=1.5),
    "coated metal": dict(base_color=[0.9, 0.55, 0.15], base_metalness=1.0,
                         specular_roughness=0.45, coat_weight=1.0, coat_roughness=0.2),
    "fuzzy fabric": dict(base_color=[0.5, 0.05, 0.2], specular_roughness=0.7, fuzz_weight=1.0,
                         fuzz_roughness=0.3),
    "brushed metal": dict(base_color=[0.8, 0.8, 0.8], base_metalness=1.0,
                          specular_roughness=0.3, specular_roughness_anisotropy=0.8),
}


def _document(name: str, inputs: dict) -> str:
    e = cx.MaterialXExport(name=name, inputs=inputs, method="set", error=None, note="")
    return cx.mtlx_document([e], what="bench_openpbr_roundtrip material")


#: a view this close to the normal (the length of its tangential part) is one where MaterialX's
#: fuzz is undefined: its LTC frame's tangent is float32 noise there (models/openpbr.py); the
#: plan's 48 pairs at theta_o = 0 rendered up to 78% off this model and moved by 0.1-78% as
#: the world frame turned about the light, where every other pair agreed to 8.6e-7
NORMAL_VIEW = 1e-6


def run_material(label: str, params: dict, wi, wo) -> dict:
    name = label.replace(" ", "_").replace("-", "_")
    if params.get("fuzz_weight", 0.0) > 0.0:  # the pairs MaterialX's fuzz does not define
        keep = np.hypot(wo[:, 0], wo[:, 1]) > NORMAL_VIEW
        undefined = int(np.sum(~keep))
        wi, wo = wi[keep], wo[keep]
    else:
        undefined = 0
    t0 = time.perf_counter()
    measured = mr.measure_in_materialx(_document(name, params), name, wi, wo).astype(np.float64)
    t_measure = time.perf_counter() - t0
    data = GonioData(wi=wi, wo=wo, value=measured / wi[:, 2:3], channels=("R", "G", "B"))
    t0 = time.perf_counter()
    sel = select(data, target="openpbr")
    t_select = time.perf_counter() - t0
    chosen = sel.candidate(sel.choice)
    export = cx.to_materialx(sel.choice, chosen.params, name + "_fit")
    document = cx.mtlx_document([export])
    valid, message = cx.validate_mtlx(document)
    again = mr.measure_in_materialx(document, export.name, wi, wo).astype(np.float64)
    rel_rms = float(np.sqrt(np.sum((again - measured) ** 2) / np.sum(measured ** 2)))
    fitted = {k: np.asarray(v, np.float64).tolist() for k, v in chosen.params.items()}
    return {
        "material": label, "set": params, "pairs": int(len(wi)), "measure_s": t_measure,
        "select_s": t_select, "candidates": [c.model for c in sel.candidates],
        "choice": sel.choice, "fitted": fitted, "error": float(chosen.error),
        "converged": bool(chosen.converged), "valid": valid, "validation": message,
        "export_vs_data_rel_rms": rel_rms, "left_out": undefined,
        "base_color_max_abs": float(np.max(np.abs(np.asarray(fitted["base_color"])
                                                  - np.asarray(params["base_color"])))),
        "roughness_abs": float(abs(fitted["specular_roughness"]
                                   - params["specular_roughness"])),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"))
    args = ap.parse_args(argv)
    import MaterialX

    plan = _plan()
    wi, wo = np.asarray(plan.wi), np.asarray(plan.wo)
    rows = []
    for label, params in MATERIALS.items():
        row = run_material(label, params, wi, wo)
        rows.append(row)
        print(f"{label}: {row['choice']} export vs data {row['export_vs_data_rel_rms']:.2e}, "
              f"select {row['select_s']:.1f} s", flush=True)
    info = {"command": "python " + " ".join(shlex.quote(a) for a in [sys.argv[0], *sys.argv[1:]]),
            "machine": machine_info(), "load": _loadavg(), "date": time.strftime("%Y-%m-%d"),
            "materialx": MaterialX.__version__, "rows": rows}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "openpbr_roundtrip.json").write_text(json.dumps(info, indent=1), encoding="utf-8")
    print(write_report(info, out))
    return 0


def write_report(info: dict, out: Path) -> str:
    rows, m = info["rows"], info["machine"]
    lines = [
        "# OpenPBR materials through MaterialX's GLSL, select --target openpbr and back",
        "",
        f"`{info['command']}`; {m['cpu_model']}, {m['cpu_count']} cores; load "
        f"{info['load']}; {info['date']}; MaterialX {info['materialx']} (GLSL on Mesa's "
        "llvmpipe).",
        "",
        f"{rows[0]['pairs']} direction pairs (four-axis plan), rendered by MaterialX's generated "
        "shader (one directional light, float32); each material fitted among the OpenPBR "
        "entries, its export validated by MaterialX and rendered again. A material with fuzz "
        "leaves out the plan's views exactly along the normal, where MaterialX's fuzz is "
        "undefined (its LTC frame's tangent is float32 noise there: NORMAL_VIEW).",
        "",
        "| material (set in MaterialX) | pairs | chosen | base colour error (max abs) | "
        "roughness error | export vs data (cos-weighted rel. RMS) | valid | select (s) |",
        "| --- | ---: | --- | ---: | ---: | ---: | --- | ---: |",
    ]
    for r in rows:
        lines.append(f"| {r['material']} ({', '.join(f'{k} {v}' for k, v in r['set'].items())}) "
                     f"| {r['pairs']} | `{r['choice']}` | {r['base_color_max_abs']:.1e} | "
                     f"{r['roughness_abs']:.1e} | {r['export_vs_data_rel_rms']:.1e} | "
                     f"{'yes' if r['valid'] else 'NO: ' + r['validation']} | "
                     f"{r['select_s']:.1f} |")
    text = "\n".join(lines) + "\n"
    (out / "openpbr_roundtrip.md").write_text(text, encoding="utf-8")
    return text


if __name__ == "__main__":
    sys.exit(main())
