"""Writing a fitted model for a renderer (``fit --export``, ``select --mitsuba/--gltf/--blender/
--mtlx``): the target's own models, the export kind from the file's extension, the write itself."""

from __future__ import annotations

import os

import numpy as np

from brdf_fit.cli._common import (
    CLIError,
    check_output_file,
)

#: export targets by output extension
EXPORT_EXT = {".xml": "mitsuba", ".gltf": "gltf", ".py": "blender", ".blend": "blender",
              ".mtlx": "openpbr"}


def target_entry(reg, model: str, target: str | None):
    """The registry entry ``model`` names; with ``--target T`` it must be written to T with no
    loss, and a bare plugin name is looked up as ``T-NAME`` (``roughplastic`` ->
    ``mitsuba-roughplastic``)."""
    if target is None:
        return reg.get(model)
    from brdf_fit.selection.selector import (
        TARGETS,
        anisotropic_candidates,
        exports_exactly,
        target_candidates,
    )

    if target not in TARGETS:
        raise CLIError(f"--target must be one of {', '.join(TARGETS)}, got {target!r}")
    for name in (model, f"{target}-{model}"):
        try:
            e = reg.get(name)
        except KeyError:
            continue
        if exports_exactly(e.name, target):
            return e
    models = (*target_candidates(target), *anisotropic_candidates(target))
    raise CLIError(f"--target {target}: {model!r} is not one of its models (written to "
                   f"{target} as fitted): {', '.join(models)}")


def export_kind(path: str | None, target: str | None) -> str | None:
    if path is None:
        return None
    ext = os.path.splitext(path)[1].lower()
    kind = EXPORT_EXT.get(ext)
    if kind is None:
        raise CLIError(f"--export: {path!r} must end in .xml (Mitsuba 3), .gltf (glTF 2.0), .py "
                       "(a Blender script), .blend (a Blender file) or .mtlx (a MaterialX OpenPBR "
                       "document)")
    if target is not None and kind != target:
        raise CLIError(f"--export {path}: a {ext} file is a {kind} export, but --target is "
                       f"{target}")
    check_output_file(path, (ext,), "--export")
    return kind


def write_export(kind: str, path: str, model: str, params: dict, data, name: str) -> dict:
    """Write ``model`` at ``params`` to ``path`` (Mitsuba XML or glTF, their round trip
    measured on the data's own geometry; a Blender script or .blend, the node's own inputs);
    returns what was written."""
    p = {k: np.asarray(v, np.float64) for k, v in params.items()}
    geometry = (data.wi, data.wo)
    if kind == "mitsuba":
        from brdf_fit.convert import mitsuba as cmi

        try:
            e = cmi.to_mitsuba(model, p, name=name, geometry=geometry)
        except cmi.ExportError as exc:
            raise CLIError(f"--export: {exc}") from None
        text = cmi.scene_document([(name, e.scene_dict)],
                                  comment=f"brdf_fit fit: {model} fitted to {name}")
        from brdf_fit.core.atomic import write_text_atomic

        write_text_atomic(path, text)
    elif kind == "blender":
        from brdf_fit.convert import blender as cb

        try:
            e = cb.to_blender(model, p, name)
            cb.write_blender(path, [e], what=f"brdf_fit fit: {model} fitted to {name}")
        except (cb.ExportError, cb.BlenderNotFound, RuntimeError, ValueError) as exc:
            raise CLIError(str(exc)) from None  # the caller's flag goes before it
    elif kind == "openpbr":
        from brdf_fit.convert import materialx as cx

        try:
            e = cx.to_materialx(model, p, name)
            cx.write_mtlx(path, [e], what=f"{model} fitted to {name}")
        except (cx.ExportError, ValueError) as exc:
            raise CLIError(f"--export: {exc}") from None
    else:
        from brdf_fit.convert import gltf as cg

        try:
            e = cg.to_gltf(model, p, name=name, geometry=geometry)
        except cg.ExportError as exc:
            raise CLIError(f"--export: {exc}") from None
        cg.write_gltf(path, [e])
    return {"target": kind, "path": path, "method": e.method, "error": e.error,
            "note": e.note}
