"""``brdf-fit select``: the cheapest model within a radiance-error budget, for one data
file or every material of a scene (``--scene``)."""

from __future__ import annotations

import math
import os

from brdf_fit.cli._common import (
    CLIError,
    Outputs,
    check_names,
    check_output_file,
    command_line,
    dense_data_of,
    load_registry,
    read_data,
    short_params,
    strict_json,
    use_x64,
)
from brdf_fit.cli._export import write_export
from brdf_fit.cli._progress import progress_callback


def run(args) -> int:
    """Fit the candidates in the radiance error, measure their costs, choose the cheapest within
    the budget (:func:`brdf_fit.selection.select`)."""
    if args.budget is not None and not (math.isfinite(args.budget) and args.budget > 0):
        raise CLIError(f"--budget must be a positive number (0.02 = 2%), got {args.budget}")
    if args.plot is not None:
        check_output_file(args.plot, (".png", ".pdf", ".svg"), "--plot")
    if (args.scene is None) == (args.data is None):
        raise CLIError("select needs a DATA file or --scene TOML (one of them)")
    if args.scene is None:
        for flag, v in (("--max-models", args.max_models),
                        ("--skip-bad", args.skip_bad or None)):
            if v is not None:
                raise CLIError(f"{flag} needs --scene")
    if args.report is not None:
        if args.scene is not None:
            raise CLIError("--report is the page of one data file's selection; a scene "
                           "writes its table and figure (--plot)")
        check_output_file(args.report, (".html",), "--report")
    if args.ceiling is not None and not args.ceiling > 0:
        raise CLIError(f"--ceiling must be a positive number (or inf), got {args.ceiling}")
    if args.target is not None:
        from brdf_fit.selection.selector import TARGETS

        if args.target not in TARGETS:
            raise CLIError(f"--target must be one of {', '.join(TARGETS)}, got "
                           f"{args.target!r}")
    if args.gltf is not None:
        check_output_file(args.gltf, (".gltf",), "--gltf")
    if args.mitsuba is not None:
        check_output_file(args.mitsuba, (".xml",), "--mitsuba")
    if args.blender is not None:
        check_output_file(args.blender, (".py", ".blend"), "--blender")
    if args.blend is not None:
        check_output_file(args.blend, (".blend",), "--blend")
    if args.mtlx is not None:
        check_output_file(args.mtlx, (".mtlx",), "--mtlx")
    reg = load_registry()
    names = None
    if args.candidates is not None and args.family is not None:
        raise CLIError("give --candidates or --family, not both")
    if args.family is not None:
        from brdf_fit.selection import family_candidates

        try:
            names = list(family_candidates(args.family))
        except ValueError as exc:
            raise CLIError(f"--family: {exc}") from None
    if args.candidates is not None:
        names = [c.strip() for c in args.candidates.split(",") if c.strip()]
        if not names:
            raise CLIError("--candidates: give at least one model name")
        names = [reg.get(n).name for n in names]  # unknown names fail before any work
    checks = check_names(args.check) if args.check else ("reciprocity", "energy")
    if args.scene is not None:
        return _select_scene(args, names, checks)
    data = read_data(args.data)
    use_x64()
    from brdf_fit.selection import select

    bar, progress = progress_callback(not args.quiet, lambda name: f"fitting {name}")
    try:
        sel = select(data, names, args.budget, target=args.target,
                     checks=() if args.no_checks else checks, ceiling=args.ceiling,
                     anisotropy=not args.no_anisotropy, progress=progress)
    except ValueError as exc:
        raise CLIError(str(exc)) from None
    finally:
        bar.close()
    doc = sel.to_dict()
    doc["data"] = args.data
    outs = Outputs()  # a failed write is reported after the result, which is printed all the same
    if args.plot is not None:
        from brdf_fit.plot import selection_front

        if outs.figure("--plot", args.plot, selection_front(sel, title=args.data)):
            doc["plot"] = args.plot
    exports = []
    chosen = sel.choice
    if chosen is not None:
        name = os.path.splitext(os.path.basename(args.data))[0]
        for flag, kind, path in (("--mitsuba", "mitsuba", args.mitsuba),
                                 ("--gltf", "gltf", args.gltf),
                                 ("--blender", "blender", args.blender),
                                 ("--blend", "blender", args.blend),
                                 ("--mtlx", "openpbr", args.mtlx)):
            if path is not None:
                # a Blender export that cannot be made (a .blend without Blender's Python, a
                # choice that is no Blender entry) is reported after the selection
                outs.write(flag, path, lambda kind=kind, path=path: exports.append(
                    write_export(kind, path, chosen, sel.candidate(chosen).params, data, name)),
                    also=(CLIError,) if kind in ("blender", "openpbr") else ())
    doc["exports"] = exports
    if args.report is not None and outs.write(
            "--report", args.report, lambda: _write_report(args, sel, data, exports)):
        doc["report"] = args.report
    status = 0 if sel.choice is not None and sel.represented else 1
    if args.json:
        print(strict_json(outs.annotate(doc)))
        return outs.status(status)
    print(f"{args.data}: {data.n} samples x {data.n_channels} channels")
    print(f"error: {sel.error_definition}")
    print(f"budget: {sel.budget:.4g} ({sel.budget_rule})")
    if sel.noise_level is not None:
        print(f"noise level (from sigma): {sel.noise_level:.4g}")
    print(f"ceiling: {sel.ceiling:.4g} ({sel.ceiling_rule})")
    if sel.anisotropy is not None:
        a = sel.anisotropy
        stat = "-" if a.statistic is None else f"{a.statistic:.3f}"
        print(f"anisotropy: statistic {stat} (threshold {a.threshold:g}): {a.note}")
    if sel.target is not None:
        print(f"target: {sel.target} (every candidate is written to it as fitted)")
    print(f"cost: {sel.cost_rule}")
    _print_candidates(sel)
    print(sel.message if sel.choice is None else
          f"choice: {sel.choice} ({short_params(sel.candidate(sel.choice).params)}), error "
          f"{sel.candidate(sel.choice).error:.4g}, {_cost_txt(sel.candidate(sel.choice))}")
    for ex in exports:
        err = ex["error"]
        print(f"export: {ex['target']} {ex['method']} "
              + ("(not verified)" if err is None else f"(round-trip error {err:.3g})")
              + f"; wrote {ex['path']}")
    if "plot" in doc:
        print(f"wrote {args.plot}")
    if "report" in doc:
        print(f"wrote {args.report}")
    return outs.status(status)


def _write_report(args, sel, data, exports) -> None:
    """``--report``: the selection's HTML page (:func:`brdf_fit.report.select_report`), whole
    or not at all; a MERL file's dense table is read again for its renders and slice."""
    from brdf_fit.core.atomic import write_text_atomic
    from brdf_fit.report import select_report

    page = select_report(sel, data, source=args.data, table=dense_data_of(data, args.data),
                         exports=exports, command=command_line(args))
    write_text_atomic(args.report, page)


def _cost_txt(c) -> str:
    rel = "" if c.cost_rel is None else f"{c.cost_rel:.2f}x Lambert (committed), "
    return f"{rel}{c.cost_ns:.3g} ns per evaluation (live)"


def _print_candidates(sel) -> None:
    w = max(len(c.model) for c in sel.candidates)
    print(f"  {'model':<{w}} {'error':>8} {'x lamb':>6} {'ns/eval':>8} {'k':>3} {'AIC':>10} "
          f"{'BIC':>10} {'chi2/dof':>9} {'conv':>5}  budget pareto checks")
    for c in sel.candidates:
        if c.message:
            print(f"  {c.model:<{w}} no fit: {c.message}")
            continue
        chi2 = "-" if c.reduced_chi2 is None else f"{c.reduced_chi2:.3g}"
        checks_txt = ",".join(f"{k}:{v}" for k, v in c.checks.items()) or "-"
        mark = "<- choice" if c.model == sel.choice else ""
        rel = "-" if c.cost_rel is None else f"{c.cost_rel:.2f}"
        print(f"  {c.model:<{w}} {c.error:8.4f} {rel:>6} {c.cost_ns:8.2f} {c.n_params:3d} "
              f"{c.aic:10.1f} {c.bic:10.1f} {chi2:>9} {'yes' if c.converged else 'no':>5}  "
              f"{'in' if c.within_budget else 'out':>6} {'*' if c.pareto else ' ':>6} "
              f"{checks_txt} {mark}")
    und = [f"{c.model}: {', '.join(c.undetermined)}" for c in sel.candidates if c.undetermined]
    if und:
        from brdf_fit.fitting.problem import UNDETERMINED_RULE

        print(f"  undetermined by the data ({UNDETERMINED_RULE}): " + "; ".join(und))
    gains = [c for c in sel.candidates if c.lobe_gain is not None]
    if gains:
        print("  what each extension's extra lobe buys (its base's error minus its own; an "
              "extension costs at least its base in the choice, and one that would be chosen is "
              "tested against it: F test of the nested pair, supported at p < 0.01):")
        for c in gains:
            g = c.lobe_gain
            test = ""
            if "supported" in g:  # tested: it would have been the choice
                verdict = ("supported" if g["supported"]
                           else "NOT supported by the data: passed over")
                test = (f"; not tested ({g['message']}): passed over" if g["p_value"] is None
                        else f"; F = {_fmt_stat(g['f_statistic'])} on {g['df'][0]}, "
                        f"{g['df'][1]} df ({g['metric']}), p = {g['p_value']:.2g}: {verdict}")
            print(f"    {c.model} over {g['base']}: {g['error_removed']:+.4g} "
                  f"({100 * g['fraction_removed']:+.1f}% of the base's error){test}")


def _fmt_stat(v) -> str:
    """An F statistic for a person: 3 digits, or "inf" for None (an exact extension)."""
    return "inf" if v is None else f"{v:.3g}"


def _select_scene(args, names, checks) -> int:
    """``select --scene``: every material's choice, the model set, the exports."""
    if args.max_models is not None and args.max_models < 1:
        raise CLIError(f"--max-models must be an integer >= 1, got {args.max_models}")
    use_x64()
    from brdf_fit.selection import scene as sc

    if args.scene == "example":
        args.scene = str(sc.EXAMPLE_SCENE)
    try:
        scene = sc.load_scene(args.scene, skip_bad=args.skip_bad)
    except sc.SceneError as exc:
        raise CLIError(str(exc)) from None
    bar, progress = progress_callback(not args.quiet, lambda what: f"fitting {what}")
    try:
        res = sc.select_scene(scene, names, args.budget, family=None, target=args.target,
                              max_models=args.max_models, skip_bad=args.skip_bad,
                              checks=() if args.no_checks or not args.check else checks,
                              ceiling=args.ceiling, progress=progress)
    except (sc.SceneError, ValueError) as exc:
        raise CLIError(str(exc)) from None
    finally:
        bar.close()
    outs = Outputs()  # a failed write is reported after the result, which is printed all the same
    if args.gltf is not None:
        outs.write("--gltf", args.gltf, lambda: sc.export_scene(res, gltf_path=args.gltf))
    if args.mitsuba is not None:
        outs.write("--mitsuba", args.mitsuba,
                   lambda: sc.export_scene(res, mitsuba_path=args.mitsuba))
    for flag, path in (("--blender", args.blender), ("--blend", args.blend)):
        if path is not None:
            from brdf_fit.convert.blender import BlenderNotFound

            outs.write(flag, path, lambda path=path: sc.export_scene(res, blender_path=path),
                       also=(BlenderNotFound, RuntimeError, ValueError))
    if args.mtlx is not None:
        outs.write("--mtlx", args.mtlx, lambda: sc.export_scene(res, mtlx_path=args.mtlx),
                   also=(ValueError,))
    doc = res.to_dict()
    if args.plot is not None:
        from brdf_fit.plot import scene_front

        outs.figure("--plot", args.plot, scene_front(res, title=res.scene.name))
    written = doc["written"] = outs.written
    status = 0 if not res.scene.bad and not res.unrepresented() else 1
    if args.json:
        print(strict_json(outs.annotate(doc)))
        return outs.status(status)
    print(f"{args.scene}: {len(res.materials)} materials ({res.seconds:.1f} s)"
          + ("" if res.materials[0].selection.target is None else
             f", target {res.materials[0].selection.target}"))
    w = max(len(c.material.name) for c in res.materials)
    wm = max(len(c.model) for c in res.materials)
    print(f"  {'material':<{w}} {'kind':<5} {'model':<{wm}} {'error':>8} {'budget':>8} "
          f"{'ns/eval':>8}  exports")
    for c in res.materials:
        ex = ", ".join(
            f"{k} failed" if "method" not in v
            else f"{k} {v['method']} " + ("(not verified)" if v["error"] is None
                                          else f"{v['error']:.2g}")
            for k, v in c.exports.items()) or "-"
        print(f"  {c.material.name:<{w}} {c.material.kind:<5} {c.model:<{wm}} {c.error:8.4f} "
              f"{c.selection.budget:8.4f} {c.cost_ns:8.2f}  {ex}")
        for n in c.material.notes:
            print(f"  {'':<{w}}   note: {n}")
        a = c.selection.anisotropy
        if a is not None and a.present:
            print(f"  {'':<{w}}   {a.note}")
        if not c.selection.represented:
            print(f"  {'':<{w}}   {c.selection.message}")
        for k, v in c.exports.items():
            if "failed" in v:
                print(f"  {'':<{w}}   {k} export failed: {v['failed']}")
    print(f"model set ({res.set_rule}): {', '.join(res.model_set)}: {len(res.model_set)} "
          f"kernel(s), {res.cost_ns_total:.3g} ns per evaluation in all, worst error "
          f"{res.worst_error:.4g}")
    for b in res.scene.bad:
        print(f"skipped: {b['error']}")
    if res.unrepresented():
        print(f"not represented by any candidate: {', '.join(res.unrepresented())} (exit "
              "status 1)")
    for path in written:
        print(f"wrote {path}")
    return outs.status(status)


def add_parser(sub) -> None:
    se = sub.add_parser("select", help="choose the cheapest model whose radiance error is "
                                       "within a budget")
    se.add_argument("data", nargs="?", default=None,
                    help="measured data (.csv, .npz, .binary); or --scene")
    se.add_argument("--scene", default=None, metavar="TOML",
                    help="a scene file: materials given as data files, MTL, glTF or registry "
                         "models (brdf_fit.selection.scene); prints the choice per material and "
                         "the model set; 'example' is the embedded example scene")
    se.add_argument("--max-models", type=int, default=None, metavar="K",
                    help="with --scene: at most K models for the whole scene (the set that "
                         "minimises the worst error)")
    se.add_argument("--gltf", default=None, metavar="OUT.gltf",
                    help="write the chosen material(s) as glTF 2.0 materials")
    se.add_argument("--mitsuba", default=None, metavar="OUT.xml",
                    help="write the chosen material(s) as Mitsuba 3 bsdfs")
    se.add_argument("--blender", default=None, metavar="OUT.py|OUT.blend",
                    help="write the chosen material(s) for Blender: a script making Principled "
                         "BSDF materials (run it in Blender), or a .blend (needs Blender's "
                         "Python: make blender); the choice must be a blender entry "
                         "(--target blender)")
    se.add_argument("--blend", default=None, metavar="OUT.blend",
                    help="the same materials saved in a .blend file (needs Blender's Python: "
                         "make blender); may be given beside --blender OUT.py")
    se.add_argument("--mtlx", default=None, metavar="OUT.mtlx",
                    help="write the chosen material(s) as a MaterialX document of OpenPBR "
                         "Surface materials; the choice must be an openpbr entry (--target "
                         "openpbr)")
    se.add_argument("--skip-bad", action="store_true",
                    help="with --scene: list bad materials and select the others")
    se.add_argument("--candidates", default=None, metavar="A,B,...",
                    help="registry names (default: lambert, oren-nayar, modified-phong, "
                         "blinn-phong, ward, beckmann, ggx, ggx-plastic, ggx-conductor, "
                         "cook-torrance)")
    se.add_argument("--family", default=None, metavar="NAME",
                    help="a named candidate set instead: diffuse, phong, microfacet, plastic, "
                         "conductor, anisotropic, default, or all (every fittable entry)")
    se.add_argument("--budget", type=float, default=None,
                    help="largest relative RMS radiance error (0.02 = 2%%; default: twice the "
                         "best candidate's error, at least 1.5x the noise level with sigma, "
                         "at least 0.01)")
    se.add_argument("--target", default=None, metavar="T",
                    help="mitsuba, gltf, blender or openpbr: select among the models the target "
                         "holds as "
                         "fitted (its native entries), so the export is the fit itself")
    se.add_argument("--ceiling", type=float, default=None, metavar="E",
                    help="error above which no candidate represents the material (default: "
                         "0.05 above the noise level; inf turns it off); then the exit "
                         "status is 1")
    se.add_argument("--no-anisotropy", action="store_true",
                    help="skip the anisotropy test (it adds anisotropic candidates when the "
                         "data need two widths)")
    se.add_argument("--check", action="append", metavar="NAME",
                    help="checks run on each fitted candidate (default: reciprocity, energy)")
    se.add_argument("--no-checks", action="store_true", help="run no checks")
    se.add_argument("--plot", default=None, metavar="PNG",
                    help="error against cost, the budget line and the choice")
    se.add_argument("--report", default=None, metavar="OUT.html",
                    help="one self-contained HTML page of the selection: every candidate, "
                         "speed against error, the choice rendered and against the data "
                         "(one data file, not --scene)")
    se.add_argument("--json", action="store_true", help="machine-readable result")
    se.add_argument("--quiet", action="store_true", help="no progress bar")
    se.set_defaults(func=run)
