"""glTF 2.0 ``materials[]`` objects of :class:`~brdf_fit.models.gltf_pbr.GltfPBR` and back:
the factors of ``pbrMetallicRoughness`` and of the five material extensions the model evaluates
(KHR_materials_ior, _specular, _anisotropy, _sheen, _clearcoat), written only where they change
the BRDF, read with the specification's defaults; lossless both ways
(tests/models/test_gltf_pbr.py).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

__all__ = ["GLTF_DEFAULTS", "GLTF_COLOURS", "to_gltf_material", "gltf_material_params"]

#: The specification's defaults of every parameter (the extensions off); also the class's.
GLTF_DEFAULTS = {
    "base_color": (1.0, 1.0, 1.0),
    "metallic": 1.0,
    "roughness": 1.0,
    "ior": 1.5,
    "specular_factor": 1.0,
    "specular_color": (1.0, 1.0, 1.0),
    "anisotropy_strength": 0.0,
    "anisotropy_rotation": 0.0,
    "sheen_color": (0.0, 0.0, 0.0),
    "sheen_roughness": 0.0,
    "clearcoat": 0.0,
    "clearcoat_roughness": 0.0,
}
GLTF_COLOURS = ("base_color", "specular_color", "sheen_color")


def _floats(name, value, n: int | None):
    """A parameter as a list of Python floats (``n`` channels, a scalar broadcast) or a float."""
    v = np.asarray(value, dtype=float).reshape(-1)
    if n is None:
        if v.size != 1:
            raise ValueError(f"{name} must be a scalar, got {v.size} values")
        return float(v[0])
    if v.size == 1:
        v = np.repeat(v, n)
    if v.size != n:
        raise ValueError(f"{name} must be RGB (3 values) or grey (1), got {v.size} values")
    return [float(x) for x in v]


def _check_range(name, v, lo=None, hi=None):
    vals = v if isinstance(v, list) else [v]
    if not all(math.isfinite(x) for x in vals):
        raise ValueError(f"{name} must be finite, got {v}")
    if (lo is not None and min(vals) < lo) or (hi is not None and max(vals) > hi):
        rng = f"[{lo:g}, {'inf' if hi is None else f'{hi:g}'}]"
        raise ValueError(f"{name} = {v} is outside the glTF range {rng}")


def to_gltf_material(params: dict, name: str) -> tuple[dict, list[str]]:
    """The glTF 2.0 ``materials[]`` object of :class:`~brdf_fit.models.gltf_pbr.GltfPBR`
    parameters (registry names; the missing ones take the specification's defaults,
    :data:`GLTF_DEFAULTS`) and the sorted extensions it uses. Lossless:
    :func:`~brdf_fit.models.gltf_pbr.from_gltf_material` of it evaluates as ``GltfPBR(**params)``
    does.

    ``pbrMetallicRoughness`` is always written. An extension is written only where it changes
    the BRDF, and in it only the values that differ from its defaults: ``KHR_materials_ior`` and
    ``KHR_materials_specular`` when ``metallic < 1`` (a pure metal has no dielectric part),
    ``KHR_materials_anisotropy`` when ``anisotropy_strength > 0``, ``KHR_materials_sheen`` when a
    sheen colour channel is > 0, ``KHR_materials_clearcoat`` when ``clearcoat > 0`` (an extension
    whose layer is off changes nothing, whatever its other values). Values outside the glTF
    ranges (which no material could hold) raise :class:`ValueError`."""
    unknown = set(params) - set(GLTF_DEFAULTS)
    if unknown:
        raise ValueError(f"not GltfPBR parameters: {sorted(unknown)}; valid: "
                         f"{', '.join(GLTF_DEFAULTS)}")
    p = {k: _floats(k, params.get(k, v), 3 if k in GLTF_COLOURS else None)
         for k, v in GLTF_DEFAULTS.items()}
    for k in ("base_color", "metallic", "roughness", "specular_factor", "anisotropy_strength",
              "sheen_color", "sheen_roughness", "clearcoat", "clearcoat_roughness"):
        _check_range(k, p[k], 0.0, 1.0)
    _check_range("specular_color", p["specular_color"], 0.0)
    _check_range("anisotropy_rotation", p["anisotropy_rotation"])
    _check_range("ior", p["ior"], 0.0)
    if 0.0 < p["ior"] < 1.0:
        raise ValueError(f"ior = {p['ior']} is not a glTF ior (0 or >= 1, KHR_materials_ior)")
    mat: dict = {
        "name": str(name),
        "pbrMetallicRoughness": {
            "baseColorFactor": p["base_color"] + [1.0],
            "metallicFactor": p["metallic"],
            "roughnessFactor": p["roughness"],
        },
    }
    ext: dict = {}
    if p["metallic"] < 1.0:
        if p["ior"] != 1.5:
            ext["KHR_materials_ior"] = {"ior": p["ior"]}
        spec = {}
        if p["specular_factor"] != 1.0:
            spec["specularFactor"] = p["specular_factor"]
        if p["specular_color"] != [1.0, 1.0, 1.0]:
            spec["specularColorFactor"] = p["specular_color"]
        if spec:
            ext["KHR_materials_specular"] = spec
    if p["anisotropy_strength"] > 0.0:
        ext["KHR_materials_anisotropy"] = {"anisotropyStrength": p["anisotropy_strength"]}
        if p["anisotropy_rotation"] != 0.0:
            ext["KHR_materials_anisotropy"]["anisotropyRotation"] = p["anisotropy_rotation"]
    if max(p["sheen_color"]) > 0.0:
        ext["KHR_materials_sheen"] = {"sheenColorFactor": p["sheen_color"]}
        if p["sheen_roughness"] != 0.0:
            ext["KHR_materials_sheen"]["sheenRoughnessFactor"] = p["sheen_roughness"]
    if p["clearcoat"] > 0.0:
        ext["KHR_materials_clearcoat"] = {"clearcoatFactor": p["clearcoat"]}
        if p["clearcoat_roughness"] != 0.0:
            ext["KHR_materials_clearcoat"]["clearcoatRoughnessFactor"] = \
                p["clearcoat_roughness"]
    if ext:
        mat["extensions"] = ext
    return mat, sorted(ext)


def gltf_material_params(material: dict) -> dict:
    """The :class:`~brdf_fit.models.gltf_pbr.GltfPBR` parameters (as arrays) of a glTF 2.0
    ``materials[]`` object: its factors with the specification's defaults, and the five
    extensions of this module where present (textures and other extensions are not read)."""
    pbr = material.get("pbrMetallicRoughness", {}) or {}
    ext = material.get("extensions", {}) or {}

    def get(block, key, default):
        return jnp.asarray((ext.get(block, {}) or {}).get(key, default), dtype=float)

    return dict(
        base_color=jnp.asarray(pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0])[:3], float),
        metallic=jnp.asarray(pbr.get("metallicFactor", 1.0), float),
        roughness=jnp.asarray(pbr.get("roughnessFactor", 1.0), float),
        ior=get("KHR_materials_ior", "ior", 1.5),
        specular_factor=get("KHR_materials_specular", "specularFactor", 1.0),
        specular_color=get("KHR_materials_specular", "specularColorFactor", [1.0, 1.0, 1.0]),
        anisotropy_strength=get("KHR_materials_anisotropy", "anisotropyStrength", 0.0),
        anisotropy_rotation=get("KHR_materials_anisotropy", "anisotropyRotation", 0.0),
        sheen_color=get("KHR_materials_sheen", "sheenColorFactor", [0.0, 0.0, 0.0]),
        sheen_roughness=get("KHR_materials_sheen", "sheenRoughnessFactor", 0.0),
        clearcoat=get("KHR_materials_clearcoat", "clearcoatFactor", 0.0),
        clearcoat_roughness=get("KHR_materials_clearcoat", "clearcoatRoughnessFactor", 0.0),
    )
