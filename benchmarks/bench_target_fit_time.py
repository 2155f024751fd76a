"""Time per fit of each renderer target's native entries: the "time per fit" column of the
targets table in docs/guide/renderers.md (issue 42).

    python benchmarks/bench_target_fit_time.py [--out DIR] [--targets mitsuba,gltf,blender,openpbr]

For every registry entry native to a target (``Entry.target``), in a fresh process per target
(no persistent compilation cache: the library leaves it off; the CLI's XLA options,
``brdf_fit._xla.configure``, applied as the command line applies them): data are the entry
itself at a coloured, mid-range parameter set away from the default start (:data:`MATERIAL`),
evaluated at the four-axis plan of bench_blender_roundtrip (524 direction pairs x 3 channels,
noise-free); ``brdf_fit.fitting.single.fit`` in the default metric from the default start (4
starts for an entry tagged "layered", or the entry's own ``select_starts``, as select fits
it), twice: the first call's wall time
includes compiling the entry's programs, the second is the fit alone. Both fits' convergence
and the largest parameter error are reported. Writes ``target_fit_time.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_eval import _loadavg, machine_info  # noqa: E402

#: the material fitted, by parameter name (each entry takes the names it has; the others keep
#: the registry default; eta and k: 0.9 x the default): coloured, mid-range, away from the
#: default start, every lobe of the entry on
MATERIAL = {
    "base_color": (0.7, 0.3, 0.1), "diffuse_reflectance": (0.7, 0.3, 0.1),
    "alpha": 0.2, "alpha_u": 0.15, "alpha_v": 0.35, "int_ior": 1.6,
    "roughness": 0.35, "specular": 0.6, "anisotropic": 0.5, "sheen": 0.5, "clearcoat": 0.6,
    "clearcoat_gloss": 0.6, "specular_factor": 0.7, "specular_color": (0.9, 0.8, 0.7),
    "anisotropy_strength": 0.6, "anisotropy_rotation": 0.4, "sheen_color": (0.3, 0.2, 0.1),
    "sheen_roughness": 0.4, "clearcoat_roughness": 0.1, "ior": 1.45, "coat_weight": 1.0,
    "coat_roughness": 0.1, "coat_ior": 1.5, "sheen_weight": 1.0,
    "base_metalness": 0.3, "specular_roughness": 0.35, "specular_ior": 1.45,
    "specular_roughness_anisotropy": 0.5, "fuzz_weight": 0.8, "fuzz_roughness": 0.4,
}
#: parameters set to this factor x their default
SCALED = {"eta": 0.9, "k": 0.9}


def _one_target(target: str) -> list[dict]:
    """In this process: every native entry of ``target`` fitted twice (module docstring)."""
    from brdf_fit import _xla

    _xla.configure()
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np
    from bench_blender_roundtrip import _plan  # the same 524 pairs

    from brdf_fit import registry
    from brdf_fit.data import GonioData
    from brdf_fit.fitting.single import fit
    from brdf_fit.selection.selector import LAYERED_STARTS

    plan = _plan()
    wi, wo = np.asarray(plan.wi), np.asarray(plan.wo)
    rows = []
    for e in registry.entries():
        if e.target != target or "delta" in e.tags:
            continue
        truth = {p.name: np.asarray(p.default_value(), np.float64) for p in e.params}
        for k in truth:
            if k in MATERIAL:
                truth[k] = np.asarray(MATERIAL[k], np.float64)
            elif k in SCALED:
                truth[k] = SCALED[k] * truth[k]
        model = e.build(**truth)
        value = np.broadcast_to(np.asarray(model.eval(wi, wo)), (len(wi), 3))
        data = GonioData(wi=wi, wo=wo, value=np.array(value), channels=("R", "G", "B"))
        # the starts select gives a layered entry (brdf_fit.selection.selector.LAYERED_STARTS)
        starts = max(LAYERED_STARTS if "layered" in e.tags else 1, e.select_starts)
        times, errs, conv = [], [], []
        for _ in range(2):
            t0 = time.perf_counter()
            r = fit(data, e.name, multistart=starts)
            times.append(time.perf_counter() - t0)
            conv.append(bool(r.converged))
            errs.append(max(float(np.max(np.abs(np.asarray(r.params[k]) - truth[k])))
                            for k in truth if k in r.params))
        rows.append({"target": target, "entry": e.name, "n_params": len(e.params),
                     "starts": starts,
                     "first_s": times[0], "warm_s": times[1], "converged": conv,
                     "max_param_error": errs[1]})
        print(f"{e.name}: first {times[0]:.1f} s, warm {times[1]:.2f} s, converged {conv}, "
              f"max parameter error {errs[1]:.1e}", file=sys.stderr, flush=True)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"))
    ap.add_argument("--targets", default="mitsuba,gltf,blender,openpbr")
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)  # the child process
    args = ap.parse_args(argv)
    if args.one:
        print(json.dumps(_one_target(args.one)))
        return 0
    rows = []
    for target in args.targets.split(","):
        out = subprocess.run([sys.executable, __file__, "--one", target], check=True,
                             stdout=subprocess.PIPE, text=True)
        rows += json.loads(out.stdout)
    info = {"command": "python " + " ".join(shlex.quote(a) for a in [sys.argv[0], *sys.argv[1:]]),
            "machine": machine_info(), "load": _loadavg(), "date": time.strftime("%Y-%m-%d"),
            "rows": rows}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "target_fit_time.json").write_text(json.dumps(info, indent=1), encoding="utf-8")
    lines = ["# Time per fit of each target's native entries", "",
             f"`{info['command']}`; {info['machine']['cpu_model']}, "
             f"{info['machine']['cpus_usable']} cores; load {info['load']}; {info['date']}.", "",
             "Each entry fitted to its own values at 524 direction pairs x 3 channels "
             "(noise-free), default metric and start, twice in a fresh process per target: "
             "the first fit includes compiling the entry's programs.", "",
             "| target | entry | starts | first fit (s, with compiling) | fit, compiled (s) | "
             "converged | largest parameter error |",
             "| --- | --- | ---: | ---: | ---: | --- | ---: |"]
    for r in rows:
        lines.append(f"| {r['target']} | `{r['entry']}` | {r['starts']} | {r['first_s']:.1f} | "
                     f"{r['warm_s']:.2f} | {'yes' if all(r['converged']) else 'no'} | "
                     f"{r['max_param_error']:.1e} |")
    text = "\n".join(lines) + "\n"
    (out / "target_fit_time.md").write_text(text, encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
