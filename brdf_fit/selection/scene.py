"""Model only what a scene needs: choose a model per material, then the set of kernels.

A **scene file** (TOML) lists materials; each ``[[material]]`` table has exactly one of

* ``data = "file.csv"`` (or ``.npz``, MERL ``.binary``): measured samples, read with
  :func:`brdf_fit.io.read`;
* ``mtl = "file.mtl"``: every material of a Wavefront MTL file (``materials = [..]`` picks some),
  each read with :func:`brdf_fit.io.mtl.read_mtl` and given the meaning
  :func:`brdf_fit.convert.mtl.mtl_model` states;
* ``gltf = "file.gltf"``: the materials of a glTF 2.0 file (``materials = [..]`` picks some by
  name), each the Appendix B metallic-roughness BRDF
  (:func:`brdf_fit.convert.gltf.appendix_b_eval`);
* ``model = "ggx"`` with ``params = {...}``: a registry model.

Relative paths are relative to the scene file. An optional ``[scene]`` table holds ``name``,
``budget``, ``max_models``, and ``candidates = [..]`` or ``family = ".."`` (the command line
overrides each).

**Samples.** A data file is selected on its own samples. A material given as a formula (MTL, glTF,
registry model) has none; it is evaluated, noise-free, on :func:`scene_geometry`, one fixed
geometry for every such material (so that each candidate compiles once per scene, not once per
material): the hemisphere grid and two lobe grids of :func:`brdf_fit.convert.phong_to_ggx.geometry`,
at half-vector widths :data:`LOBE_WIDTHS` (a sharp lobe and a broad one; every grid has the exact
mirror direction at each incidence, so even a lobe sharper than the first is sampled at its peak).

**Per material** :func:`brdf_fit.selection.select` runs with the scene's candidates and budget
(without a budget, select's default per material); the cost of a model is measured once per
scene and shared by every material (it is the cost of one kernel).

**The model set**: the distinct chosen models, one kernel each; the scene's total cost is the sum
of their costs (ns per evaluation each) and its worst error the largest error of a material's
choice. With ``max_models = K`` the set is the one of at most K candidates that **minimises the
worst error** over the materials, each material taking its lowest-error model of the set
(ties: fewer models, then the lower total cost); every K-subset of the fitted candidates is tried
(10 candidates: 385 sets for K = 3), so the cost is the per-material fits, not the search.

**Bad input** (an unknown material kind, a missing file, a malformed MTL line, an invalid glTF
material, a parameter out of range) is a :class:`SceneError` whose one line names the file and
the line; with ``skip_bad`` the bad materials are listed in the result and the others selected.
Every input is read before any fit, so a bad one never costs a finished fit.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import os
import pathlib
import re
import time
import tomllib
from collections.abc import Callable, Sequence

import jax.numpy as jnp
import numpy as np

from brdf_fit import io, registry
from brdf_fit.convert import gltf as cgltf
from brdf_fit.convert import mtl as cmtl
from brdf_fit.convert.phong_to_ggx import geometry as lobe_geometry
from brdf_fit.core.atomic import write_text_atomic
from brdf_fit.core.validate import ParameterError
from brdf_fit.data import DataError, GonioData
from brdf_fit.fitting.problem import FitError
from brdf_fit.io.mtl import MtlError, read_mtl
from brdf_fit.models._base import evaluate
from brdf_fit.selection.anisotropy import THRESHOLD as ANISO_THRESHOLD
from brdf_fit.selection.anisotropy import AnisotropyTest
from brdf_fit.selection.selector import (
    DEFAULT_CANDIDATES,
    TARGETS,
    Selection,
    family_candidates,
    select,
    target_candidates,
)

__all__ = ["EXAMPLE_SCENE", "KINDS", "LOBE_WIDTHS", "SceneError", "SceneMaterial", "Scene",
           "MaterialChoice", "SceneSelection", "best_model_set", "export_scene", "load_scene",
           "scene_geometry", "select_scene", "with_max_models"]

#: the embedded example scene (``brdf-fit select --scene example``): an MTL file of an OBJ export,
#: a measured-style gonioreflectometer file and a registry model
EXAMPLE_SCENE = pathlib.Path(__file__).resolve().parents[1] / "resources" / "scenes" / "example" \
    / "scene.toml"
#: the material kinds of a scene file, one key each
KINDS = ("data", "mtl", "gltf", "model")
#: half-vector widths (radians) of the lobe grids of :func:`scene_geometry`
LOBE_WIDTHS = (0.05, 0.3)
#: largest zenith of either direction in :func:`scene_geometry` (degrees)
SCENE_MAX_ZENITH_DEG = 80.0
_MATERIAL_KEYS = {"name", "materials", "params", *KINDS}
_SCENE_KEYS = {"name", "budget", "max_models", "candidates", "family", "target"}


class SceneError(ValueError):
    """A bad scene or material; the message is one line, ``"{path}:{line}: {problem}"``."""

    def __init__(self, path, line: int, problem: str, material: str | None = None):
        self.path, self.line, self.problem, self.material = str(path), int(line), problem, material
        where = self.path if self.line == 0 else f"{self.path}:{self.line}"  # 0: the file
        super().__init__(" ".join(f"{where}: {problem}".split()))


@dataclasses.dataclass
class SceneMaterial:
    """One material of a scene: its ``name``, ``kind`` (:data:`KINDS`), ``source`` (a file, or
    the registry model), the scene-file ``line`` of its table, the samples it is selected on,
    and ``notes`` (what its conversion dropped or approximated)."""

    name: str
    kind: str
    source: str
    line: int
    data: GonioData
    notes: list[str] = dataclasses.field(default_factory=list)
    #: whether the material's own formula is anisotropic (None: measured data, unknown; the
    #: selection then tests the data for it)
    anisotropic: bool | None = None


@dataclasses.dataclass
class Scene:
    """A loaded scene: materials in file order, the ``[scene]`` settings, the bad materials
    (``skip_bad``) as ``(where, message)``."""

    path: str
    name: str
    materials: list[SceneMaterial]
    settings: dict
    bad: list[dict]


def scene_geometry(max_zenith_deg: float = SCENE_MAX_ZENITH_DEG) -> tuple[np.ndarray, np.ndarray]:
    """``(wi, wo)``: the fixed geometry formula materials are evaluated on (module docstring):
    the union of :func:`brdf_fit.convert.phong_to_ggx.geometry` at each of
    :data:`LOBE_WIDTHS`, duplicates removed, in a deterministic order."""
    parts = [lobe_geometry(w, max_zenith_deg) for w in LOBE_WIDTHS]
    wi = np.concatenate([p[0] for p in parts])
    wo = np.concatenate([p[1] for p in parts])
    _, keep = np.unique(np.round(np.concatenate([wi, wo], 1), 12), axis=0, return_index=True)
    keep = np.sort(keep)
    return np.ascontiguousarray(wi[keep]), np.ascontiguousarray(wo[keep])


def _synth(values, wi, wo, source: str) -> GonioData:
    v = np.asarray(values, np.float64)
    v = np.broadcast_to(v[:, None] if v.ndim == 1 else v, (wi.shape[0], 3))
    return GonioData(wi=wi, wo=wo, value=np.array(v), channels=("R", "G", "B"),
                     metadata={"source": source, "geometry": "brdf_fit.selection.scene_geometry"})


def _table_lines(text: str) -> list[int]:
    """1-based line numbers of the ``[[material]]`` headers, in order (tomllib gives none)."""
    pat = re.compile(r"^\s*\[\[\s*material\s*\]\]")
    return [i for i, ln in enumerate(text.splitlines(), 1) if pat.match(ln)]


def _settings(doc: dict, path: str, text: str) -> dict:
    s = doc.get("scene", {})
    line = next((i for i, ln in enumerate(text.splitlines(), 1)
                 if re.match(r"^\s*\[\s*scene\s*\]", ln)), 1)
    if not isinstance(s, dict):
        raise SceneError(path, line, "[scene] must be a table")
    unknown = sorted(set(s) - _SCENE_KEYS)
    if unknown:
        raise SceneError(path, line, f"[scene]: unknown key {unknown[0]!r}; known: "
                         + ", ".join(sorted(_SCENE_KEYS)))
    b = s.get("budget")
    if b is not None and not (isinstance(b, int | float) and math.isfinite(b) and b > 0):
        raise SceneError(path, line, f"[scene] budget must be a positive number, got {b!r}")
    k = s.get("max_models")
    if k is not None and not (isinstance(k, int) and not isinstance(k, bool) and k >= 1):
        raise SceneError(path, line, f"[scene] max_models must be an integer >= 1, got {k!r}")
    if "candidates" in s and "family" in s:
        raise SceneError(path, line, "[scene]: give candidates or family, not both")
    if "target" in s and s["target"] not in TARGETS:
        raise SceneError(path, line, f"[scene] target must be one of {', '.join(TARGETS)}, "
                         f"got {s['target']!r}")
    try:
        if "family" in s:
            family_candidates(s["family"])
        for c in s.get("candidates", []):
            registry.get(c)
    except (KeyError, ValueError) as exc:
        raise SceneError(path, line, f"[scene]: {exc}") from None
    return dict(s)


def _resolve(base: str, rel) -> str:
    return rel if os.path.isabs(rel) else os.path.join(base, rel)


def _pick(names_in_file: list[str], wanted, path, line, what) -> list[str]:
    if wanted is None:
        return names_in_file
    if not (isinstance(wanted, list) and all(isinstance(w, str) for w in wanted)):
        raise SceneError(path, line, "materials must be a list of names")
    missing = [w for w in wanted if w not in names_in_file]
    if missing:
        raise SceneError(path, line, f"{what} has no material {missing[0]!r}; it has "
                         + ", ".join(names_in_file))
    return list(wanted)


def _materials_of(entry: dict, path: str, line: int, base: str, geom, skip_bad: bool):
    """The scene materials one ``[[material]]`` table gives, and the bad ones (skip_bad)."""
    unknown = sorted(set(entry) - _MATERIAL_KEYS)
    if unknown:
        raise SceneError(path, line, f"unknown key {unknown[0]!r} in [[material]]; a material "
                         "has one of " + ", ".join(KINDS) + " (and name, materials, params)")
    kinds = [k for k in KINDS if k in entry]
    if len(kinds) != 1:
        raise SceneError(path, line, "unknown material kind: give exactly one of "
                         + ", ".join(KINDS) + (f" (got {', '.join(kinds)})" if kinds else ""))
    kind = kinds[0]
    src = entry[kind]
    if not isinstance(src, str) or not src:
        raise SceneError(path, line, f"{kind} must be a non-empty string")
    name = entry.get("name")
    wi, wo = geom
    if kind == "data":
        file = _resolve(base, src)
        try:
            d = io.read(file)
        except DataError as exc:
            raise SceneError(path, line, f"data: {exc}") from None
        return [SceneMaterial(name or os.path.splitext(os.path.basename(src))[0], kind, file,
                              line, d)], []
    if kind == "model":
        params = entry.get("params", {})
        if not isinstance(params, dict):
            raise SceneError(path, line, "params must be a table")
        try:
            e = registry.get(src)
            m = e.build(**{k: np.asarray(v, np.float64) for k, v in params.items()})
            if "delta" in e.tags:
                raise ParameterError(f"{e.name} is a delta lobe: it has no samples to select on")
        except (KeyError, ParameterError, ValueError, TypeError) as exc:
            raise SceneError(path, line, f"model {src}: {exc}") from None
        vals = evaluate(m, jnp.asarray(wi), jnp.asarray(wo))
        return [SceneMaterial(name or e.name, kind, e.name, line,
                              _synth(vals, wi, wo, f"registry {e.name}"),
                              anisotropic=bool(m.is_anisotropic()))], []
    file = _resolve(base, src)
    out, bad = [], []
    if kind == "mtl":
        try:
            res = read_mtl(file, skip_bad=skip_bad)
        except MtlError as exc:
            raise SceneError(path, line, f"mtl: {exc}") from None
        mats, errs = (res.materials, res.errors) if skip_bad else (res, [])
        bad += [{"material": e.material, "where": f"{e.path}:{e.line}", "error": str(e)}
                for e in errs]
        by = {m.name: m for m in mats}
        for n in _pick(list(by), entry.get("materials"), path, line, file):
            mm = by[n]
            meaning = cmtl.mtl_model(mm)
            built = meaning.build()
            vals = evaluate(built, jnp.asarray(wi), jnp.asarray(wo))
            out.append(SceneMaterial(n, kind, mm.where, line,
                                     _synth(vals, wi, wo, f"MTL {mm.where} as {meaning.name}"),
                                     list(meaning.notes),
                                     anisotropic=bool(built.is_anisotropic())))
        return out, bad
    # gltf
    try:
        mats = cgltf.read_gltf_materials(file)
    except (cgltf.ExportError, ValueError) as exc:
        raise SceneError(path, line, f"gltf: {exc}") from None
    by = dict(mats)
    for n in _pick(list(by), entry.get("materials"), path, line, file):
        vals = cgltf.appendix_b_eval(by[n], jnp.asarray(wi), jnp.asarray(wo))
        out.append(SceneMaterial(n, kind, f"{file}#{n}", line,
                                 _synth(vals, wi, wo, f"glTF {file} material {n}"),
                                 anisotropic=False))  # read as Appendix B: isotropic
    return out, bad


def load_scene(path, skip_bad: bool = False) -> Scene:
    """Read a scene file and every material it names (module docstring). Raises
    :class:`SceneError` at the first bad material; with ``skip_bad`` bad materials are collected
    in ``Scene.bad`` (a bad scene file as a whole still raises)."""
    path = str(path)
    try:
        with open(path, "rb") as fh:
            text = fh.read().decode("utf-8-sig")
    except OSError as exc:
        raise SceneError(path, 0, f"cannot read the scene file ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise SceneError(path, 0, "not a UTF-8 text file") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+)", str(exc))
        raise SceneError(path, int(m.group(1)) if m else 0, f"not valid TOML: {exc}") from None
    unknown = sorted(set(doc) - {"scene", "material"})
    if unknown:
        raise SceneError(path, 0, f"unknown top-level key {unknown[0]!r}; a scene has [scene] "
                         "and [[material]] tables")
    settings = _settings(doc, path, text)
    entries = doc.get("material", [])
    if not isinstance(entries, list) or not entries:
        raise SceneError(path, 0, "no materials: add [[material]] tables")
    lines = _table_lines(text)
    lines += [0] * (len(entries) - len(lines))
    base = os.path.dirname(os.path.abspath(path))
    geom = scene_geometry()
    materials, bad = [], []
    for entry, line in zip(entries, lines, strict=True):
        try:
            got, b = _materials_of(entry, path, line, base, geom, skip_bad)
        except SceneError as exc:
            if not skip_bad:
                raise
            bad.append({"material": entry.get("name"), "where": f"{exc.path}:{exc.line}",
                        "error": str(exc)})
            continue
        materials += got
        bad += b
    names = [m.name for m in materials]
    dup = next((n for n in names if names.count(n) > 1), None)
    if dup is not None:
        raise SceneError(path, next(m.line for m in materials if m.name == dup),
                         f"two materials are named {dup!r}: give each a distinct name")
    if not materials:
        raise SceneError(path, 0, "no material could be read: " + "; ".join(
            b["error"] for b in bad))
    return Scene(path=path, name=settings.get("name", os.path.basename(path)),
                 materials=materials, settings=settings, bad=bad)


@dataclasses.dataclass
class MaterialChoice:
    """One material's outcome: its selection and the model the scene gives it."""

    material: SceneMaterial
    selection: Selection | None
    model: str | None
    error: float
    cost_ns: float
    exports: dict = dataclasses.field(default_factory=dict)

    def candidate(self):
        return None if self.model is None else self.selection.candidate(self.model)

    def to_dict(self) -> dict:
        c = self.candidate()
        return {
            "name": self.material.name, "kind": self.material.kind,
            "source": self.material.source, "line": self.material.line,
            "n_samples": self.material.data.n, "notes": self.material.notes,
            "model": self.model,
            "params": ({} if c is None else {k: np.asarray(v).tolist()
                                             for k, v in c.params.items()}),
            "error": _num(self.error), "cost_ns": _num(self.cost_ns),
            "budget": None if self.selection is None else self.selection.budget,
            "own_choice": None if self.selection is None else self.selection.choice,
            "exports": self.exports,
            "selection": None if self.selection is None else self.selection.to_dict(),
        }


def _num(x):
    return float(x) if x is not None and math.isfinite(x) else None


@dataclasses.dataclass
class SceneSelection:
    """The outcome of :func:`select_scene` (module docstring)."""

    scene: Scene
    materials: list[MaterialChoice]
    model_set: list[str]
    cost_ns_total: float
    worst_error: float
    max_models: int | None
    set_rule: str
    costs: dict
    seconds: float

    def unrepresented(self) -> list[str]:
        """Materials no candidate represents (their selection's ``represented`` is False)."""
        return [m.material.name for m in self.materials if not m.selection.represented]

    def to_dict(self) -> dict:
        return {
            "scene": self.scene.path, "name": self.scene.name,
            "model_set": self.model_set, "n_kernels": len(self.model_set),
            "cost_ns_total": _num(self.cost_ns_total), "worst_error": _num(self.worst_error),
            "max_models": self.max_models, "set_rule": self.set_rule,
            "costs_ns": {k: _num(v) for k, v in sorted(self.costs.items())},
            "materials": [m.to_dict() for m in self.materials],
            "unrepresented": self.unrepresented(),
            "bad": self.scene.bad, "seconds": round(self.seconds, 3),
        }


def best_model_set(errors: np.ndarray, costs: Sequence[float], k: int) -> tuple[int, ...]:
    """Indices of at most ``k`` columns of ``errors`` (materials x candidates; inf where a
    candidate has no fit) that minimise the worst over rows of the row's smallest error in the
    set; ties: fewer columns, then the lower summed ``costs``. Exhaustive over the subsets."""
    n = errors.shape[1]
    best, key = None, None
    for size in range(1, min(k, n) + 1):
        for sub in itertools.combinations(range(n), size):
            worst = float(np.max(np.min(errors[:, sub], axis=1)))
            kk = (worst, size, float(sum(costs[j] for j in sub)))
            if key is None or kk < key:
                best, key = sub, kk
    return best


def select_scene(scene: Scene, candidates: Sequence[str] | None = None,
                 budget: float | None = None, *, family: str | None = None,
                 target: str | None = None, max_models: int | None = None,
                 skip_bad: bool = False, checks: Sequence[str] = (),
                 ceiling: float | None = None,
                 progress: Callable[[int, int, str], None] | None = None) -> SceneSelection:
    """Select a model for every material of ``scene`` and the scene's model set (module
    docstring). Arguments left None take the scene file's ``[scene]`` settings. ``target``:
    select in the models of a renderer or format (:func:`brdf_fit.selection.select`), so the
    exports are the fits themselves. A material whose every candidate fails is a
    :class:`SceneError`, or with ``skip_bad`` listed in ``scene.bad`` (the materials already
    selected are kept either way in the result)."""
    t0 = time.perf_counter()
    st = scene.settings
    target = st.get("target") if target is None else target
    if candidates is None and family is None:
        candidates, family = st.get("candidates"), st.get("family")
    names = (None if candidates is None and family is None else
             list(family_candidates(family) if family is not None else candidates))
    budget = st.get("budget") if budget is None else budget
    max_models = st.get("max_models") if max_models is None else max_models
    if max_models is not None and max_models < 1:
        raise ValueError(f"max_models must be >= 1, got {max_models}")
    costs: dict[str, float] = {}
    n_cand = len(names) if names is not None else len(
        DEFAULT_CANDIDATES if target is None else target_candidates(target))
    total = len(scene.materials) * n_cand
    choices: list[MaterialChoice] = []
    for i, mat in enumerate(scene.materials):
        def sub(done, _n, model, i=i, mat=mat):
            if progress is not None:
                progress(i * n_cand + min(done, n_cand), total, f"{mat.name}: {model}")
        known = (True if mat.anisotropic is None else AnisotropyTest(
            statistic=None, threshold=ANISO_THRESHOLD, present=mat.anisotropic,
            measurable=True, note=("anisotropic" if mat.anisotropic else "isotropic")
            + f" by its formula ({mat.kind} material: no test needed)"))
        try:
            sel = select(mat.data, names, budget, target=target, checks=checks, progress=sub,
                         costs=costs, ceiling=ceiling, anisotropy=known)
        except (FitError, ParameterError, ValueError) as exc:
            err = SceneError(scene.path, mat.line, f"material {mat.name!r}: {exc}", mat.name)
            if not skip_bad:
                raise err from None
            scene.bad.append({"material": mat.name, "where": f"{scene.path}:{mat.line}",
                              "error": str(err)})
            continue
        choices.append(MaterialChoice(mat, sel, None, float("inf"), float("nan")))
    if progress is not None:
        progress(total, total, "done")
    if not choices:
        raise SceneError(scene.path, 0, "no material could be selected")
    union = list(dict.fromkeys(c.model for ch in choices for c in ch.selection.candidates))
    return _assign(scene, choices, union, costs, max_models, time.perf_counter() - t0)


def with_max_models(result: SceneSelection, max_models: int | None) -> SceneSelection:
    """The same scene's choice under another ``max_models`` (None: each material's own
    choice), from the fits already made: no candidate is fitted again."""
    if max_models is not None and max_models < 1:
        raise ValueError(f"max_models must be >= 1, got {max_models}")
    choices = [MaterialChoice(c.material, c.selection, None, float("inf"), float("nan"))
               for c in result.materials]
    names = list(dict.fromkeys(c.model for ch in result.materials
                               for c in ch.selection.candidates))
    return _assign(result.scene, choices, names, result.costs, max_models, result.seconds)


def _assign(scene, choices, names, costs, max_models, seconds) -> SceneSelection:
    """Give every material its model (module docstring: own choice, or the K-model set)."""
    if max_models is None:
        rule = "each material's own choice (the cheapest candidate within its budget)"
        for c in choices:
            own = c.selection.choice
            if own is None:  # nothing within budget: the lowest error, said so
                own = min((x for x in c.selection.candidates if not x.message),
                          key=lambda x: x.error).model
            c.model = own
    else:
        cand = list(names)
        err = np.array([[_err(c.selection, n) for n in cand] for c in choices])
        sub_ = best_model_set(err, [costs.get(n, math.inf) for n in cand], max_models)
        rule = (f"at most {max_models} model(s): the set that minimises the worst error; each "
                "material takes its lowest-error model of the set")
        for r, c in enumerate(choices):
            j = min(sub_, key=lambda j, r=r: err[r, j])
            c.model = cand[j]
    for c in choices:
        cc = c.selection.candidate(c.model)
        c.error, c.cost_ns = float(cc.error), float(cc.cost_ns)
    model_set = sorted({c.model for c in choices}, key=lambda n: (costs.get(n, math.inf), n))
    return SceneSelection(
        scene=scene, materials=choices, model_set=model_set,
        cost_ns_total=float(sum(costs[n] for n in model_set)),
        worst_error=float(max(c.error for c in choices)), max_models=max_models,
        set_rule=rule, costs=dict(costs), seconds=seconds)


def _err(sel: Selection, name: str) -> float:
    try:
        c = sel.candidate(name)
    except KeyError:  # not a candidate of this material (e.g. an anisotropic one)
        return float("inf")
    return float("inf") if c.message else float(c.error)


def _params(c) -> dict:
    return {k: np.asarray(v, np.float64) for k, v in c.params.items()}


def _export_each(result: SceneSelection, target: str, export, error_type, extra=None):
    """``export(model, params, name=, geometry=)`` of every material's choice, on the
    material's own samples; the outcome recorded in ``exports[target]`` (method, error, note,
    ``extra(e)``; or ``failed`` with the reason). Returns ``(choice, export)`` of the successes."""
    done = []
    for c in result.materials:
        d = c.material.data
        try:
            e = export(c.model, _params(c.candidate()), name=c.material.name,
                       geometry=(d.wi, d.wo))
        except error_type as exc:
            c.exports[target] = {"failed": str(exc)}
            continue
        c.exports[target] = {"method": e.method, "error": _num(e.error), "note": e.note,
                             **(extra(e) if extra else {})}
        done.append((c, e))
    return done


def export_scene(result: SceneSelection, gltf_path=None, mitsuba_path=None,
                 blender_path=None, mtlx_path=None) -> list[str]:
    """Write the scene's chosen materials as a glTF 2.0 document (``gltf_path``, materials only:
    :func:`brdf_fit.convert.gltf.to_gltf`) and as a Mitsuba 3 scene of ``<bsdf>`` elements
    (``mitsuba_path``: :func:`brdf_fit.convert.mitsuba.to_mitsuba`) and for Blender
    (``blender_path``: a material script or a .blend, :func:`brdf_fit.convert.blender
    .to_blender`; only ``blender-principled*`` choices) and as a MaterialX document
    (``mtlx_path``: :func:`brdf_fit.convert.materialx.to_materialx`; only ``openpbr-surface*``
    choices). Each export's method and
    its radiance error against the chosen model, measured on the material's own samples, is
    recorded in the material's ``exports``; a model a target cannot hold is recorded there as
    ``failed`` (the other materials are still written). Returns the paths written."""
    written = []
    if gltf_path is not None:
        exports = _export_each(result, "gltf", cgltf.to_gltf, cgltf.ExportError, lambda e: {
            "extensions_used": e.extensions_used})
        cgltf.write_gltf(gltf_path, [e for _, e in exports])
        written.append(str(gltf_path))
    if mitsuba_path is not None:
        from brdf_fit.convert import mitsuba as cmi

        done = _export_each(result, "mitsuba", cmi.to_mitsuba, cmi.ExportError)
        text = cmi.scene_document(
            [(c.material.name, e.scene_dict) for c, e in done],
            comment=(f"brdf_fit select, scene {os.path.basename(result.scene.path)}: one bsdf "
                     "per material (alpha, not roughness)"))
        write_text_atomic(mitsuba_path, text)
        written.append(str(mitsuba_path))
    if blender_path is not None:
        from brdf_fit.convert import blender as cb

        done = _export_each(result, "blender", cb.to_blender, cb.ExportError)
        cb.write_blender(blender_path, [e for _, e in done],
                         what=f"brdf_fit select, scene {os.path.basename(result.scene.path)}")
        written.append(str(blender_path))
    if mtlx_path is not None:
        from brdf_fit.convert import materialx as cx

        done = _export_each(result, "openpbr", cx.to_materialx, cx.ExportError)
        cx.write_mtlx(mtlx_path, [e for _, e in done],
                      what=f"brdf_fit select, scene {os.path.basename(result.scene.path)}")
        written.append(str(mtlx_path))
    return written
