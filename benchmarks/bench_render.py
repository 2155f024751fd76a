"""How fast is a preview? ``brdf_fit.render.render_sphere`` against Mitsuba 3 rendering the
same scene (issue 46).

    python benchmarks/bench_render.py [--size 256] [--repeats 5]   # writes results/render.{json,md}

The scene of :mod:`brdf_fit.render`: a unit sphere, an orthographic camera, a directional light
at 45 degrees, direct illumination only, ``--size`` x ``--size`` pixels. Per model
(``mitsuba-roughconductor``, ``mitsuba-roughplastic``, ``ggx``, ``disney``): the first call in
this process (it compiles the model's program for this size) and the best of ``--repeats`` warm
calls with new parameter values each time (what a user changing a slider waits for). Then the
same under a constant environment at 64 samples per pixel (multiple importance sampling), and
under a lat-long environment map (:func:`brdf_fit.envmap.sky_texels`, 64 x 128, a sky with
a sun). The
baseline, in the same run: Mitsuba 3's ``mi.render`` of the same scene at one sample per pixel
(64 under the environment) with its ``direct`` integrator, in the ``scalar_rgb`` variant (best
of ``--repeats``, after a first render), for the two Mitsuba models; ``llvm_ad_rgb`` too where
Dr.Jit finds LLVM (``DRJIT_LIBLLVM_PATH``). Mitsuba renders 1 jittered sample per pixel; ours
evaluates the pixel centres: the same number of BSDF evaluations.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_eval import machine_info  # noqa: E402

from brdf_fit import registry  # noqa: E402
from brdf_fit.convert.mitsuba import to_mitsuba  # noqa: E402
from brdf_fit.envmap import sky_texels  # noqa: E402
from brdf_fit.render import FRAME_HALF_WIDTH, IRRADIANCE, render_sphere  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")
#: model -> the parameter a warm call changes, and its values
MODELS = {"mitsuba-roughconductor": ("alpha", (0.1, 0.2, 0.3)),
          "mitsuba-roughplastic": ("alpha", (0.1, 0.2, 0.3)),
          "ggx": ("alpha", (0.1, 0.2, 0.3)),
          "disney": ("roughness", (0.3, 0.5, 0.7))}
LIGHT_ZENITH_DEG = 45.0


def time_ours(name: str, size: int, repeats: int) -> dict:
    entry = registry.get(name)
    key, values = MODELS[name]
    t = time.perf_counter()
    render_sphere(entry.build(), size, LIGHT_ZENITH_DEG)
    first = time.perf_counter() - t
    warm = []
    for k in range(repeats):
        m = entry.build(**{key: values[k % len(values)]})
        t = time.perf_counter()
        render_sphere(m, size, LIGHT_ZENITH_DEG)
        warm.append(time.perf_counter() - t)
    return {"first_s": first, "warm_best_s": min(warm), "warm_s": warm}


#: samples per pixel of the timed environment previews
ENV_SPP = 64


def time_ours_environment(name: str, size: int, repeats: int, envmap: bool = False) -> dict:
    """A constant environment (or :func:`sky_texels` with ``envmap``) at :data:`ENV_SPP`
    samples per pixel: first call, best warm."""
    from brdf_fit.envmap import LatLongEnvironment
    from brdf_fit.render import render_sphere_environment

    env = LatLongEnvironment.of(sky_texels()) if envmap else None
    entry = registry.get(name)
    key, values = MODELS[name]
    t = time.perf_counter()
    render_sphere_environment(entry.build(), size, samples_per_pixel=ENV_SPP, environment=env)
    first = time.perf_counter() - t
    warm = []
    for k in range(max(1, repeats // 2)):
        t = time.perf_counter()
        render_sphere_environment(entry.build(**{key: values[k % len(values)]}), size,
                                  samples_per_pixel=ENV_SPP, seed=k + 1, environment=env)
        warm.append(time.perf_counter() - t)
    return {"first_s": first, "warm_best_s": min(warm), "warm_s": warm}


def time_mitsuba(name: str, size: int, repeats: int, variant: str,
                 environment: bool | str = False) -> dict | None:
    try:
        import mitsuba as mi

        mi.set_variant(variant)
    except Exception as e:  # no Mitsuba, or no such variant (Dr.Jit finds no LLVM)
        return {"skipped": f"{variant}: {type(e).__name__}: {e}"}
    T = mi.ScalarTransform4f
    theta = np.radians(LIGHT_ZENITH_DEG)
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "direct"},
        "sensor": {"type": "orthographic",
                   "to_world": T().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0])
                   @ T().scale([FRAME_HALF_WIDTH, FRAME_HALF_WIDTH, 1]),
                   "film": {"type": "hdrfilm", "width": size, "height": size},
                   "sampler": {"type": "independent", "sample_count": 1}},
        "sphere": {"type": "sphere",
                   "bsdf": to_mitsuba(name, {}, verify=False).scene_dict},
        "light": ({"type": "envmap", "bitmap": mi.Bitmap(sky_texels().astype(np.float32))}
                  if environment == "map" else
                  {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}}
                  if environment else
                  {"type": "directional", "direction": [-np.sin(theta), 0.0, -np.cos(theta)],
                   "irradiance": {"type": "rgb", "value": IRRADIANCE}}),
    })
    spp = ENV_SPP if environment else 1
    t = time.perf_counter()
    np.asarray(mi.render(scene, spp=spp))
    first = time.perf_counter() - t
    warm = []
    for _ in range(repeats if not environment else max(1, repeats // 2)):
        t = time.perf_counter()
        np.asarray(mi.render(scene, spp=spp))
        warm.append(time.perf_counter() - t)
    return {"first_s": first, "warm_best_s": min(warm), "warm_s": warm}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", default=RESULTS)
    args = ap.parse_args()
    info = machine_info()
    rows = []
    for name in MODELS:
        row = {"model": name, "ours": time_ours(name, args.size, args.repeats),
               "ours_environment": time_ours_environment(name, args.size, args.repeats),
               "ours_envmap": time_ours_environment(name, args.size, args.repeats, True)}
        if name.startswith("mitsuba-"):
            for variant in ("scalar_rgb", "llvm_ad_rgb"):
                row[variant] = time_mitsuba(name, args.size, args.repeats, variant)
                row[variant + "_environment"] = time_mitsuba(name, args.size, args.repeats,
                                                             variant, environment=True)
                row[variant + "_envmap"] = time_mitsuba(name, args.size, args.repeats,
                                                        variant, environment="map")
        rows.append(row)
        print(json.dumps(row))
    doc = {"command": "python benchmarks/bench_render.py " + " ".join(sys.argv[1:]),
           "size": args.size, "repeats": args.repeats, "machine": info, "rows": rows}
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "render.json"), "w", encoding="utf-8") as fh:
        json.dump(doc, fh, indent=2)

    def cell(d):
        if d is None or "skipped" in d:
            return "n/a"
        return f"{d['warm_best_s'] * 1e3:.1f} ms (first {d['first_s']:.2f} s)"

    def table(suffix: str) -> list[str]:
        """The markdown table of one lighting (``suffix``: "" directional, "_environment")."""
        out = ["| model | ours | Mitsuba scalar_rgb | ratio | Mitsuba llvm_ad_rgb | ratio |",
               "|---|---:|---:|---:|---:|---:|"]
        for row in rows:
            ours = row["ours" + suffix]
            cells = [row["model"], cell(ours)]
            for variant in ("scalar_rgb", "llvm_ad_rgb"):
                d = row.get(variant + suffix)
                cells += [cell(d), "n/a" if d is None or "skipped" in d
                          else f"{d['warm_best_s'] / ours['warm_best_s']:.2f}x"]
            out.append("| " + " | ".join(cells) + " |")
        return out

    lines = ["# Sphere previews: brdf_fit.render against Mitsuba 3 (issue 46)", "",
             f"Command: `{doc['command']}`  ",
             f"Date: {info['date_utc']}  ",
             f"Machine: {info['cpu_model']}, {info['cpus_usable']} cores usable, "
             f"jax {info['jax']}", "",
             f"{args.size} x {args.size} pixels, a directional light at {LIGHT_ZENITH_DEG:g} "
             "degrees, direct illumination. Ours: a warm call with new parameter values (best "
             f"of {args.repeats}) and, in brackets, the first call in the process (compiling). "
             "Mitsuba 3: `mi.render` at 1 sample per pixel, `direct` integrator (best of "
             f"{args.repeats} after a first render). Ratio: Mitsuba's warm time over ours.", "",
             *table("")]
    lines += ["", f"A constant environment, {ENV_SPP} samples per pixel (ours: multiple "
              "importance sampling of the model's sampler and the environment's, one of each "
              "per sample; Mitsuba: `direct` with its `constant` emitter, which samples the "
              "emitter and the BSDF too). Ours: best of the warm calls and the first.", "",
              *table("_environment")]
    lines += ["", f"A lat-long environment map (`sky_texels`: 64 x 128, a sky and a 400x sun), "
              f"{ENV_SPP} samples per pixel (ours: the map's patches drawn by radiance times "
              "solid angle against the model's sampler; Mitsuba: `direct` with its `envmap` "
              "emitter of the same texels).", "", *table("_envmap")]
    with open(os.path.join(args.out, "render.md"), "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
