"""Issue 28's round trip through a renderer: data rendered by Mitsuba 3, selected and fitted for
Mitsuba, exported, and evaluated in Mitsuba again.

    python benchmarks/bench_renderer_roundtrip.py [--target mitsuba] [--out DIR]

1. The nine recipes of ``examples/renderer/`` (gold GGX conductor, copper Beckmann conductor,
   Mitsuba's own ``roughplastic``, brushed (anisotropic) aluminium, and five ``principled``
   materials: a plastic, the same with a clearcoat, a rough blue with sheen, a dielectric with
   tinted specular, a brushed metal) are rendered by
   Mitsuba 3's ``BSDF.eval`` (``scalar_rgb``) on a four-axis gonioreflectometer plan: 2,853
   samples each, noise-free (``--noise SIGMA``: with multiplicative lognormal noise, the files
   carrying sigma, and each export compared with the noise-free render too).
2. One scene file lists the nine data files; ``brdf-fit select --scene S --target mitsuba
   --mitsuba S.xml --gltf S.gltf --json`` runs in a fresh process (timed), exactly as a user
   runs it (``--target ''`` runs it without a target: the package's default candidates), with
   an empty compilation cache of its own (``BRDF_FIT_CACHE_DIR``), as on a first run.
3. The written XML is parsed with Python's strict ``xml.etree``, loaded with Mitsuba's
   ``load_file``, and each material's ``<bsdf>`` is evaluated in Mitsuba at its data file's
   directions: the relative RMS radiance error against the data is what a renderer given the
   export reproduces. The glTF file is validated with the Khronos glTF validator (npm
   ``gltf-validator``, installed into a cache folder when node and npm are present), else with
   the JSON schema check of the tests.

Writes ``renderer_roundtrip.md`` and ``renderer_roundtrip.json`` to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(ROOT / "tests"))
from bench_eval import _loadavg, machine_info  # noqa: E402

from data_synth.recipes import synthesize  # noqa: E402

RECIPES = ("gold_ggx", "copper_beckmann", "plastic_ggx", "aluminium_aniso", "principled_plastic",
           "principled_clearcoat", "principled_sheen", "principled_tinted", "principled_brushed")


def _mitsuba_errors(xml_path: Path, datas: dict) -> dict:
    """Each ``<bsdf id=...>`` of the written scene evaluated in Mitsuba at its data's
    directions: relative RMS radiance error against the data."""
    import mitsuba as mi

    from brdf_fit.selection.selector import radiance_error

    mi.set_variant("scalar_rgb")
    mi.load_file(str(xml_path))  # the whole file loads
    loaded = dict(_bsdfs(mi, xml_path))
    return {name: (radiance_error(data, _eval(mi, loaded[name], data.wi, data.wo))
                   if name in loaded else None) for name, data in datas.items()}


def _bsdfs(mi, xml_path: Path):
    """``(id, bsdf)`` of every top-level bsdf in the file, each loaded on its own."""
    tree = ET.parse(xml_path)
    for el in tree.getroot().findall("bsdf"):
        el.set("version", "3.0.0")
        yield el.get("id"), mi.load_string(ET.tostring(el, encoding="unicode"))


def _eval(mi, bsdf, wi, wo):
    ctx = mi.BSDFContext()
    frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    out = np.zeros((wi.shape[0], 3))
    for n in range(wi.shape[0]):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*(float(x) for x in wo[n]))
        si.sh_frame = frame
        v = bsdf.eval(ctx, si, mi.Vector3f(*(float(x) for x in wi[n])))
        out[n] = [float(v[0]), float(v[1]), float(v[2])] if wi[n, 2] > 0 else 0.0
    return out / np.maximum(wi[:, 2:3], 1e-300)


def validate_gltf(path: Path) -> dict:
    """The Khronos validator's issue counts (``{"validator": ..., "numErrors": ...}``), or the
    JSON-schema check when node/npm are not there."""
    from _khronos import khronos_validate

    rep = khronos_validate(path)
    if rep is not None:
        return rep
    import jsonschema

    schema = json.loads((ROOT / "tests" / "convert" / "gltf_material.schema.json").read_text())
    errs = list(jsonschema.Draft202012Validator(schema).iter_errors(json.loads(path.read_text())))
    return {"validator": "tests/convert/gltf_material.schema.json (jsonschema)",
            "numErrors": len(errs), "numWarnings": 0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--target", default="mitsuba", help="mitsuba (default), gltf, or '' (none)")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"))
    ap.add_argument("--name", default="renderer_roundtrip")
    ap.add_argument("--noise", type=float, default=0.0, metavar="SIGMA",
                    help="multiplicative lognormal noise on every file (0.02 = 2%%; the files "
                         "then carry sigma, and each export is also compared with the "
                         "noise-free render)")
    args = ap.parse_args(argv)
    info = machine_info()
    import tomllib

    from brdf_fit import io

    work = Path(tempfile.mkdtemp(prefix="brdf_rt_"))
    datas, clean = {}, {}
    for r in RECIPES:
        recipe = tomllib.loads((ROOT / "examples" / "renderer" / f"{r}.toml").read_text())
        clean[r] = d = synthesize(recipe)
        if args.noise > 0:
            recipe["noise"] = [{"type": "lognormal", "args": {"sigma": args.noise}}]
            d = synthesize(recipe)
        io.write(d, str(work / f"{r}.csv"))
        datas[r] = d
    scene = work / "scene.toml"
    scene.write_text("[scene]\nname = \"renderer files of issue 28\"\n\n" + "".join(
        f"[[material]]\nname = \"{r}\"\ndata = \"{r}.csv\"\n\n" for r in RECIPES))
    xml_path, gltf_path = work / "scene.xml", work / "scene.gltf"
    cmd = [str(Path(sys.executable).parent / "brdf-fit"), "select", "--scene", str(scene),
           "--mitsuba", str(xml_path), "--gltf", str(gltf_path), "--json", "--quiet"]
    if args.target:
        cmd += ["--target", args.target]
    t0 = time.perf_counter()
    # an empty compilation cache, as on a user's first run (a warm one halves the time)
    env = dict(os.environ, BRDF_FIT_CACHE_DIR=str(work / "jax_cache"))
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if not proc.stdout.strip():
        print(proc.stderr, file=sys.stderr)
        return 2
    doc = json.loads(proc.stdout)
    ET.parse(xml_path)  # raises when not well-formed
    errors = _mitsuba_errors(xml_path, datas)
    errors_clean = _mitsuba_errors(xml_path, clean) if args.noise > 0 else {}
    gl = validate_gltf(gltf_path)
    rows = []
    for m in doc["materials"]:
        sel = m["selection"]
        ex = m["exports"].get("mitsuba", {})
        # an extension chosen (a lobe over its base): the base's own error on the same data
        by_model = {c["model"]: c for c in sel["candidates"]}
        gain = (by_model.get(m["model"]) or {}).get("lobe_gain") or {}
        base = by_model.get(gain.get("base"), {})
        rows.append({
            "base": base.get("model"), "base_error": base.get("error"),
            "material": m["name"], "choice": m["model"], "represented": sel["represented"],
            "fit_error": m["error"], "budget": m["budget"],
            "anisotropy": (sel["anisotropy"] or {}).get("statistic"),
            "anisotropic_choice": "aniso" in (m["model"] or ""),
            "export_method": ex.get("method"), "export_roundtrip": ex.get("error"),
            "mitsuba_vs_data": errors.get(m["name"]),
            "mitsuba_vs_noise_free": errors_clean.get(m["name"]),
            "gltf": m["exports"].get("gltf", {}),
        })
    seconds: dict = {}
    for m in doc["materials"]:
        for c in m["selection"]["candidates"]:
            seconds[c["model"]] = seconds.get(c["model"], 0.0) + c["seconds"]
        a = m["selection"]["anisotropy"] or {}
        seconds["(anisotropy test)"] = seconds.get("(anisotropy test)", 0.0) + a.get("seconds",
                                                                                    0.0)
    info["loadavg_end"] = _loadavg()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    command = "python benchmarks/bench_renderer_roundtrip.py " + shlex.join(argv or sys.argv[1:])
    res = {"command": command.strip(), "machine": info, "select_command": shlex.join(cmd),
           "exit_status": proc.returncode, "wall_seconds": wall, "rows": rows,
           "xml_well_formed": True, "gltf_validation": gl,
           "scene_seconds": doc["seconds"], "model_set": doc["model_set"],
           "seconds_per_candidate": seconds}
    (out / f"{args.name}.json").write_text(json.dumps(res, indent=1) + "\n")
    lines = [f"# Renderer round trip ({'target ' + args.target if args.target else 'no target'})",
             "", "Command:", "", f"    {res['command']}", "",
             f"Machine: {info.get('cpu_model')}, {info.get('cpu_count')} cores, jax "
             f"{info.get('jax')}, {info.get('date_utc')}, load {info.get('loadavg_start')} -> "
             f"{info.get('loadavg_end')}", "",
             f"`brdf-fit select --scene ... {'--target ' + args.target if args.target else ''}` "
             f"in a fresh process with an empty compilation cache: {wall:.1f} s wall, exit "
             f"status {proc.returncode}; the XML "
             f"parses with xml.etree; glTF: {gl.get('validator')}: {gl.get('numErrors')} "
             f"errors, {gl.get('numWarnings')} warnings."
             + (f" Noise: multiplicative lognormal, sigma {args.noise:g}, on every file (the "
                "files carry sigma)." if args.noise > 0 else ""), "",
             "| material | chosen | represented | fit error | its base's error | anisotropy "
             "statistic | export | export round trip | exported bsdf in Mitsuba vs the data |"
             + (" ... vs the noise-free render |" if args.noise > 0 else ""),
             "|---|---|---|---:|---:|---:|---|---:|---:|" + ("---:|" if args.noise > 0 else "")]
    for r in rows:
        def f(x):
            return "-" if x is None else f"{x:.3g}"
        base = "-" if r["base"] is None else f"{f(r['base_error'])} ({r['base']})"
        lines.append(f"| {r['material']} | {r['choice']} | {r['represented']} | "
                     f"{f(r['fit_error'])} | {base} | {f(r['anisotropy'])} | "
                     f"{r['export_method']} | {f(r['export_roundtrip'])} | "
                     f"{f(r['mitsuba_vs_data'])} |"
                     + (f" {f(r['mitsuba_vs_noise_free'])} |" if args.noise > 0 else ""))
    lines += ["", "Seconds per candidate over the materials (fit, checks, cost; the "
              "first material of each candidate compiles its programs):", "",
              "| candidate | seconds |", "|---|---:|"]
    lines += [f"| {k} | {v:.1f} |" for k, v in sorted(seconds.items(), key=lambda kv: -kv[1])]
    (out / f"{args.name}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
