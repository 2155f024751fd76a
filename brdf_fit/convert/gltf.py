"""Export a registry model as a glTF 2.0 metallic-roughness material, verified by round trip.

The target's semantics are the BRDF of the glTF 2.0 specification, Appendix B ("BRDF
Implementation", KhronosGroup/glTF ``specification/2.0/Specification.adoc``), with the
``KHR_materials_ior`` and ``KHR_materials_specular`` extensions (KhronosGroup/glTF
``extensions/2.0/Khronos/KHR_materials_{ior,specular}/README.md``). :func:`appendix_b_eval`
implements it as written there (``L`` = ``wi``, toward the light; ``V`` = ``wo``, toward the
viewer; ``H = normalize(L + V)``)::

    alpha     = roughness^2                                   (clamped to ALPHA_MIN, see below)
    D         = alpha^2 chi+(N.H) / (pi ((N.H)^2 (alpha^2 - 1) + 1)^2)
    Vis       = chi+(H.L) chi+(H.V) / (2 (|N.V| sqrt(alpha^2 + (1 - alpha^2)(N.L)^2)
                                          + |N.L| sqrt(alpha^2 + (1 - alpha^2)(N.V)^2)))
    specular_brdf = Vis D               (height-correlated Smith, Appendix B.3.2)
    diffuse_brdf  = baseColor / pi
    fresnel_w     = (1 - |V.H|)^5
    metal_brdf    = specular_brdf (baseColor + (1 - baseColor) fresnel_w)     (conductor_fresnel)
    f0_ior        = ((ior - 1)/(ior + 1))^2                   (KHR_materials_ior; default 1.5)
    dielectric_f0 = min(f0_ior specularColor, 1) specularFactor   (KHR_materials_specular)
    dielectric_f90 = specularFactor
    F             = dielectric_f0 + (dielectric_f90 - dielectric_f0) fresnel_w   (RGB)
    dielectric_brdf = F specular_brdf + (1 - max(F.r, F.g, F.b)) diffuse_brdf
    material      = mix(dielectric_brdf, metal_brdf, metallic)

Without the extensions (``ior = 1.5``, ``specularFactor = 1``, ``specularColor = 1``) ``F`` is
grey and ``dielectric_brdf`` is the base specification's ``fresnel_mix``,
``mix(diffuse_brdf, specular_brdf, 0.04 + 0.96 fresnel_w)``. ``ior = 0`` (the
specular-glossiness compatibility mode) gives ``f0_ior = 1`` from the same formula. The
specification forbids evaluating ``alpha = 0`` with these formulas; ``alpha`` is clamped to
:data:`brdf_fit.core.numerics.ALPHA_MIN` (1e-4), as the registry's microfacet models are.
Directions below the surface give 0 (the package's convention; with both directions above the
surface ``H.L > 0`` and ``H.V > 0``, so the ``chi+`` factors are 1).

:func:`to_gltf` maps a registry model to that material:

* **exact** (the error is rounding): ``ggx`` (GGX, height-correlated Smith, Schlick ``f0`` per
  channel) is glTF's metal branch: ``metallic = 1``, ``baseColor = f0``,
  ``roughness = sqrt(alpha)``. ``lambert`` is the dielectric branch with the specular lobe
  switched off: ``metallic = 0``, ``baseColor = rho``, ``KHR_materials_specular``
  ``specularFactor = 0`` (then ``F = 0`` and ``dielectric_brdf = diffuse_brdf``).
* **fitted** (everything else that evaluates): ``baseColor`` (3), ``metallic``, ``roughness``,
  ``specularFactor`` and ``specularColorFactor`` (3; ``ior`` stays 1.5: for reflection it is
  degenerate with ``specularColor``) are fitted to the source's values on the geometry by
  Levenberg-Marquardt (optimistix) in the cos-weighted radiance least squares, which is the
  reported error itself; each parameter is mapped through ``(1 + sin u)/2`` onto its glTF
  range (so it is valid by construction); a metal fit (metallic 1) and a dielectric fit
  (metallic 0) are made and the better one kept (:data:`METAL_PREFERENCE`).
  ``KHR_materials_specular`` is written only where it differs from its defaults and the material
  is not a pure metal.

``error`` (:data:`ERROR_MEASURE`) is measured on the stated geometry, all channels, in float64:
``sqrt(sum ((f_src - f_gltf) cos_i)^2 / sum (f_src cos_i)^2)``. It is the error of
``GltfExport.material`` (full float64 precision); :func:`gltf_document` rounds to
:data:`DOCUMENT_DIGITS` significant digits, which changes the BRDF by about 1e-6 relative.

Measured at default parameters on the default geometry: ggx 2.0e-15 and lambert 0 (exact);
fitted: ggx-ms 6.0e-4, ggx-ms-turquin 2.0e-3, ggx-plastic 4.6e-3 (dielectric),
ggx-conductor 5.7e-3 (metal), ggx-separable 2.5e-2, oren-nayar 7.5e-2, beckmann 0.19,
cook-torrance 0.22, the anisotropic entries 0.36-0.45 (glTF without KHR_materials_anisotropy
is isotropic), the Phong family 0.43-0.57. Every registry entry but the delta ``mirror``
exports.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from brdf_fit import registry
from brdf_fit._version import __version__
from brdf_fit.convert.error import radiance_error
from brdf_fit.convert.phong_to_ggx import GRID, LOBE_N_PHI, LOBE_S, LOBE_THETA_I_DEG, geometry
from brdf_fit.core.atomic import write_text_atomic
from brdf_fit.core.numerics import ALPHA_MIN, INV_PI
from brdf_fit.core.params import UnknownModelError
from brdf_fit.core.validate import ParameterError
from brdf_fit.models.gltf_pbr import from_gltf_material

__all__ = [
    "ExportError",
    "GltfExport",
    "ERROR_MEASURE",
    "SUPPORTED_EXTENSIONS",
    "DOCUMENT_DIGITS",
    "appendix_b_eval",
    "default_geometry",
    "radiance_error",
    "source_rgb",
    "export_source",
    "lobe_width",
    "to_gltf",
    "gltf_document",
    "write_gltf",
    "read_gltf_materials",
]

ERROR_MEASURE = ("relative RMS radiance error sqrt(sum ((f_src - f_export) cos_i)^2 / "
                 "sum (f_src cos_i)^2) over the geometry, all channels")
#: extensions evaluated by the native model (brdf_fit.models.gltf_pbr) rather than _appendix_b
_LAYER_EXTENSIONS = ("KHR_materials_anisotropy", "KHR_materials_sheen", "KHR_materials_clearcoat")
#: material extensions this module writes and reads (anything else required is refused)
SUPPORTED_EXTENSIONS = ("KHR_materials_ior", "KHR_materials_specular", *_LAYER_EXTENSIONS)
#: significant digits of the floats :func:`gltf_document` writes (a relative change <= 5e-7)
DOCUMENT_DIGITS = 6
#: models refused by tag, with the reason
_REFUSED_TAGS = {"delta": "it is a delta (mirror) lobe: eval is 0 everywhere, glTF has no delta "
                          "BRDF and nothing can be fitted to it"}
#: largest useful specularColorFactor with ior 1.5: f0 = min(0.04 c, 1) is flat beyond 1/0.04
_SPEC_COLOR_MAX = 25.0
_VERSION_RE = re.compile(r"^[0-9]+\.[0-9]+$")


class ExportError(ValueError):
    """A model that cannot be exported, or a glTF file/material that cannot be read (one line,
    naming the model, or the file and the material index)."""


@dataclasses.dataclass
class GltfExport:
    """Outcome of :func:`to_gltf` (see the module docstring).

    ``material``: the glTF ``materials[]`` object; ``extensions_used``: the extensions it uses;
    ``method``: "exact" or "fitted"; ``note``: one line saying why; ``error``:
    :data:`ERROR_MEASURE` of ``material`` against the source; ``geometry``: a sentence naming the
    geometry; ``n_samples``: its direction pairs; ``source`` / ``params``: what was exported."""

    source: str
    params: dict
    material: dict
    extensions_used: list
    method: str
    note: str
    error: float
    geometry: str
    n_samples: int

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["params"] = {k: np.asarray(v).tolist() for k, v in self.params.items()}
        d["error_measure"] = ERROR_MEASURE
        return d


# ----------------------------------------------------------------------------- Appendix B


def _material_arrays(material: dict):
    """``(base (3,), metallic, roughness, ior, specular_factor, specular_color (3,))`` of a glTF
    material with the specification's defaults."""
    pbr = material.get("pbrMetallicRoughness", {}) or {}
    ext = material.get("extensions", {}) or {}
    base = jnp.asarray(pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0]), float)[:3]
    metallic = jnp.asarray(pbr.get("metallicFactor", 1.0), float)
    rough = jnp.asarray(pbr.get("roughnessFactor", 1.0), float)
    ior = jnp.asarray(ext.get("KHR_materials_ior", {}).get("ior", 1.5), float)
    spec = ext.get("KHR_materials_specular", {})
    sf = jnp.asarray(spec.get("specularFactor", 1.0), float)
    sc = jnp.asarray(spec.get("specularColorFactor", [1.0, 1.0, 1.0]), float)
    return base, metallic, rough, ior, sf, sc


def _appendix_b(base, metallic, rough, ior, sf, sc, wi, wo):
    """The Appendix B kernel on ``(N, 3)`` directions (module docstring); ``(N, 3)`` values."""
    lx, ly, lz = wi[..., 0], wi[..., 1], wi[..., 2]
    vx, vy, vz = wo[..., 0], wo[..., 1], wo[..., 2]
    valid = (lz > 0) & (vz > 0)
    # sanitise invalid lanes to the normal before any formula sees them (double where)
    lx, ly, lz = (jnp.where(valid, lx, 0.0), jnp.where(valid, ly, 0.0),
                  jnp.where(valid, lz, 1.0))
    vx, vy, vz = (jnp.where(valid, vx, 0.0), jnp.where(valid, vy, 0.0),
                  jnp.where(valid, vz, 1.0))
    hx, hy, hz = lx + vx, ly + vy, lz + vz
    inv = jax.lax.rsqrt(hx * hx + hy * hy + hz * hz)  # > 0: both directions above the surface
    hx, hy, hz = hx * inv, hy * inv, hz * inv
    n_l, n_v, n_h = lz, vz, hz
    v_h = jnp.abs(vx * hx + vy * hy + vz * hz)
    alpha = jnp.maximum(rough * rough, ALPHA_MIN)
    a2 = alpha * alpha
    d = n_h * n_h * (a2 - 1.0) + 1.0
    D = a2 * INV_PI / (d * d)
    vis = 0.5 / (n_v * jnp.sqrt(a2 + (1.0 - a2) * n_l * n_l)
                 + n_l * jnp.sqrt(a2 + (1.0 - a2) * n_v * n_v))
    specular = (vis * D)[..., None]
    fw = ((1.0 - v_h) ** 5)[..., None]
    diffuse = INV_PI * base
    metal = specular * (base + (1.0 - base) * fw)
    f0_ior = ((ior - 1.0) / (ior + 1.0)) ** 2
    f0 = jnp.minimum(f0_ior * sc, 1.0) * sf
    F = f0 + (sf - f0) * fw
    dielectric = F * specular + (1.0 - jnp.max(F, axis=-1, keepdims=True)) * diffuse
    out = (1.0 - metallic) * dielectric + metallic * metal
    return jnp.where(valid[..., None], out, 0.0)


def appendix_b_eval(material: dict, wi, wo):
    """The glTF 2.0 metallic-roughness BRDF of ``material`` (a ``materials[]`` object, with
    ``KHR_materials_ior`` and ``KHR_materials_specular`` where present; other extensions are
    ignored) at ``(N, 3)`` directions ``wi`` (toward the light) and ``wo`` (toward the viewer):
    ``(N, 3)`` RGB values of f in 1/sr, without the cosine (module docstring)."""
    wi = jnp.asarray(wi)
    wo = jnp.asarray(wo)
    ext = material.get("extensions", {}) or {}
    if any(e in ext for e in _LAYER_EXTENSIONS):
        # the layered extensions: the native model of brdf_fit.models.gltf_pbr (held to a
        # NumPy transcription of the extensions' texts in tests/models/test_gltf_pbr.py)
        return from_gltf_material(material).eval(wi, wo)
    return _appendix_b(*_material_arrays(material), wi, wo)


# ----------------------------------------------------------------------------- geometry


def default_geometry(width: float = 0.5, max_zenith_deg: float = 80.0):
    """``(wi, wo, sentence)``: the hemisphere + lobe grid of
    :func:`brdf_fit.convert.phong_to_ggx.geometry` for a lobe of width ``width`` (radians in
    half-vector space; :func:`to_gltf` passes the source's ``alpha``, or 0.5 without one)."""
    wi, wo = geometry(float(width), float(max_zenith_deg))
    text = (
        f"hemisphere grid (theta_i, theta_o on linspace(0, {max_zenith_deg:g} deg, "
        f"{GRID['n_theta_i']}/{GRID['n_theta_o']}), phi_i = 0, {GRID['n_phi']} phi_o) + lobe grid "
        f"(theta_i in {', '.join(f'{t:g}' for t in LOBE_THETA_I_DEG)} deg, half vectors at "
        f"theta_h = s w, s = 0..{LOBE_S[-1]:g} step {LOBE_S[1]:g}, {LOBE_N_PHI} phi_h, "
        f"w = {width:.4g} rad); both directions within {max_zenith_deg:g} deg of the normal; "
        f"{wi.shape[0]} direction pairs")
    return wi, wo, text


# ----------------------------------------------------------------------------- export


def export_source(model_name: str, params: dict | None):
    """``(entry, built model, all parameters as arrays)`` of a model to export; an unknown
    model, a refused one (a delta lobe) or invalid parameters are an :class:`ExportError`."""
    try:
        entry = registry.get(model_name)
    except UnknownModelError as e:
        raise ExportError(f"cannot export {model_name!r}: {e}") from None
    for tag, why in _REFUSED_TAGS.items():
        if tag in entry.tags:
            raise ExportError(f"cannot export {entry.name!r}: {why}")
    params = dict(params or {})
    try:
        with jax.enable_x64(True):  # exports are measured in float64 (module docstring)
            model = entry.build(**params)
    except ParameterError as e:
        raise ExportError(f"cannot export {entry.name!r}: {e}") from None
    full = entry.defaults()
    full.update({k: np.asarray(v, float) for k, v in params.items()})
    return entry, model, full


def source_rgb(model, wi, wo, name: str) -> np.ndarray:
    """The model's values as ``(N, 3)`` float64 RGB (mono broadcast); other channel counts are
    an :class:`ExportError` (glTF and Mitsuba's RGB variants take RGB)."""
    with jax.enable_x64(True):
        f = np.asarray(model.eval(jnp.asarray(wi, float), jnp.asarray(wo, float)), float)
    f = f.reshape(f.shape[0], -1)
    if f.shape[1] == 1:
        f = np.repeat(f, 3, axis=1)
    if f.shape[1] != 3:
        raise ExportError(f"cannot export {name!r}: it has {f.shape[1]} channels; the target "
                          f"takes RGB (give RGB or scalar colour parameters)")
    if not np.all(np.isfinite(f)):
        raise ExportError(f"cannot export {name!r}: it evaluates to non-finite values on the "
                          f"geometry")
    return f


def _material(name, base, metallic, rough, sf=1.0, sc=(1.0, 1.0, 1.0)) -> tuple[dict, list]:
    mat = {
        "name": name,
        "pbrMetallicRoughness": {
            "baseColorFactor": [float(b) for b in base] + [1.0],
            "metallicFactor": float(metallic),
            "roughnessFactor": float(rough),
        },
    }
    ext = {}
    if float(metallic) < 1.0 and (float(sf) != 1.0 or any(float(c) != 1.0 for c in sc)):
        spec = {}
        if float(sf) != 1.0:
            spec["specularFactor"] = float(sf)
        if any(float(c) != 1.0 for c in sc):
            spec["specularColorFactor"] = [float(c) for c in sc]
        ext["KHR_materials_specular"] = spec
    if ext:
        mat["extensions"] = ext
    return mat, sorted(ext)


def _to_unit(u):
    """``[0, 1]`` from an unconstrained ``u``: ``(1 + sin u)/2``. Unlike a logistic, it reaches
    the ends at a finite ``u`` (where its derivative vanishes), so a fit whose optimum lies on a
    bound (specularFactor 1, a black channel) stops there instead of creeping toward infinity
    until the step limit (measured: the dielectric fit of ggx-plastic took all 200 steps with a
    logistic)."""
    return 0.5 * (1.0 + jnp.sin(u))


def _from_unit(x):
    """Inverse of :func:`_to_unit` on ``[0, 1]`` (ends moved in by 1e-6)."""
    x = np.clip(np.asarray(x, float), 1e-6, 1.0 - 1e-6)
    return np.arcsin(2.0 * x - 1.0)


#: the metal fit is kept unless the dielectric fit's error is smaller by more than this factor
#: (a metal is the simpler, physically meaningful reading of a conductor; measured on
#: ggx-conductor's defaults the two differ by 0.4%)
METAL_PREFERENCE = 1.05


def _unpack(u, metal: bool):
    """Physical glTF parameters ``(base, metallic, roughness, specularFactor,
    specularColorFactor)`` from the unconstrained vector: metal family ``[base 3, roughness]``
    (metallic 1), dielectric family ``[base 3, roughness, specularFactor, specularColor 3]``
    (metallic 0), each through ``(1 + sin u)/2`` onto its glTF range."""
    base = _to_unit(u[0:3])
    rough = _to_unit(u[3])
    if metal:
        one = jnp.ones((), u.dtype)
        return base, one, rough, one, jnp.ones(3, u.dtype)
    return base, jnp.zeros((), u.dtype), rough, _to_unit(u[4]), _SPEC_COLOR_MAX * _to_unit(u[5:8])


@jax.jit(static_argnames=("metal",))
def _fit_gltf(u0, wi, wo, f_src, mask, metal: bool):
    c = wi[:, 2:3] * mask[:, None]
    scale = 1.0 / jnp.sqrt(jnp.sum((f_src * c) ** 2))
    ior = jnp.asarray(1.5, f_src.dtype)

    def residuals(u, _):
        base, metallic, rough, sf, sc = _unpack(u, metal)
        f = _appendix_b(base, metallic, rough, ior, sf, sc, wi, wo)
        return ((f_src - f) * c * scale).ravel()

    sol = optx.least_squares(residuals, optx.LevenbergMarquardt(rtol=1e-8, atol=1e-10), u0,
                             max_steps=MAX_STEPS, throw=False)
    r = residuals(sol.value, None)
    return sol.value, jnp.sum(r * r), sol.stats["num_steps"]


#: the fit's arrays are padded (mask 0) to a multiple of this many pairs, so that geometries of
#: similar size share one compiled fit (a compile costs ~2 s; measured)
_PAD = 512


def _padded(wi, wo, f_src):
    n = wi.shape[0]
    m = -(-n // _PAD) * _PAD
    pad = m - n
    up = np.tile([0.0, 0.0, 1.0], (pad, 1))
    mask = np.concatenate([np.ones(n), np.zeros(pad)])
    return (np.concatenate([wi, up]), np.concatenate([wo, up]),
            np.concatenate([f_src, np.zeros((pad, 3))]), mask)


#: Levenberg-Marquardt step limit per start
MAX_STEPS = 200


def _fitted(f_src, wi, wo, width):
    """The glTF parameters of the better of a metal and a dielectric fit (module docstring;
    :data:`METAL_PREFERENCE`), and a note naming the fits."""
    r0 = math.sqrt(min(max(width, 0.01), 1.0))
    fits = {}
    with jax.enable_x64(True):
        args = tuple(jnp.asarray(a, float) for a in _padded(wi, wo, f_src))
        for metal in (True, False):
            u0 = [_from_unit(np.full(3, 0.5)), _from_unit([r0])]
            if not metal:
                u0 += [_from_unit([0.9]), _from_unit(np.full(3, 1.0 / _SPEC_COLOR_MAX))]
            u, loss, steps = _fit_gltf(jnp.asarray(np.concatenate(u0)), *args, metal=metal)
            loss = float(loss)
            fits[metal] = (math.sqrt(loss) if math.isfinite(loss) else math.inf,
                           tuple(np.asarray(x, float) for x in _unpack(u, metal)), int(steps))
    metal = fits[True][0] <= METAL_PREFERENCE * fits[False][0]
    base, metallic, rough, sf, sc = fits[metal][1]
    note = (f"metal fit error {fits[True][0]:.3g} ({fits[True][2]} steps), dielectric fit "
            f"error {fits[False][0]:.3g} ({fits[False][2]} steps): kept the "
            f"{'metal' if metal else 'dielectric'} fit")
    return base, float(metallic), float(rough), float(sf), sc, note


def lobe_width(params: dict) -> float:
    """The lobe width the default geometry is built for: ``alpha``, ``sqrt(alpha_x alpha_y)``,
    or 0.5 for a model without one."""
    if "alpha" in params:
        return float(np.asarray(params["alpha"]).reshape(-1)[0])
    if "alpha_x" in params and "alpha_y" in params:
        return float(math.sqrt(float(np.asarray(params["alpha_x"]).reshape(-1)[0])
                               * float(np.asarray(params["alpha_y"]).reshape(-1)[0])))
    return 0.5


def to_gltf(model_name: str, params: dict | None = None, *, name: str | None = None,
            geometry=None) -> GltfExport:
    """Export registry model ``model_name`` at ``params`` (defaults for the rest) as a glTF 2.0
    material (module docstring: the exact cases, the fit, the error). ``geometry``: ``(wi, wo)``
    arrays of the directions to match and measure on (default :func:`default_geometry` at the
    source's width). A delta lobe, an unknown model, invalid parameters or a non-RGB model
    raise :class:`ExportError`."""
    entry, model, full = export_source(model_name, params)
    name = entry.name if name is None else str(name)
    width = lobe_width(full)
    if geometry is None:
        wi, wo, text = default_geometry(width)
    else:
        wi, wo = (np.asarray(g, float) for g in geometry)
        if wi.ndim != 2 or wi.shape[-1] != 3 or wi.shape != wo.shape or wi.shape[0] == 0:
            raise ExportError(f"cannot export {entry.name!r}: geometry must be two (N, 3) arrays "
                              f"of equal shape, got {wi.shape} and {wo.shape}")
        text = f"user geometry: {wi.shape[0]} direction pairs"
    f_src = source_rgb(model, wi, wo, entry.name)
    if entry.target == "gltf":
        mat, ext = entry.native_export(full)
        mat = {**mat, "name": name}
        method = "exact"
        note = (f"native entry: {entry.name} is the glTF material model itself "
                "(brdf_fit.models.gltf_pbr), every parameter written as fitted")
    elif entry.name == "ggx":
        f0 = np.broadcast_to(full["f0"], (3,))
        mat, ext = _material(name, f0, 1.0, math.sqrt(float(full["alpha"])))
        method = "exact"
        note = ("glTF's metal branch is GGX with height-correlated Smith and Schlick F0 = "
                "baseColor: metallic 1, baseColor = f0, roughness = sqrt(alpha)")
    elif entry.name == "lambert":
        rho = np.broadcast_to(full["rho"], (3,))
        mat, ext = _material(name, rho, 0.0, 1.0, sf=0.0)
        method = "exact"
        note = ("glTF's dielectric branch with KHR_materials_specular specularFactor 0 is "
                "baseColor/pi: metallic 0, baseColor = rho")
    else:
        base, metallic, rough, sf, sc, how = _fitted(f_src, wi, wo, width)
        mat, ext = _material(name, base, metallic, rough, sf, sc)
        method = "fitted"
        note = (f"{entry.name} is not a glTF metallic-roughness BRDF; glTF parameters fitted in "
                f"the cos-weighted radiance least squares on the geometry; {how}")
    with jax.enable_x64(True):
        f_exp = np.asarray(appendix_b_eval(mat, jnp.asarray(wi, float), jnp.asarray(wo, float)))
    err = radiance_error(f_src, f_exp, wi)
    return GltfExport(source=entry.name, params=full, material=mat, extensions_used=ext,
                      method=method, note=note, error=err, geometry=text, n_samples=wi.shape[0])


# ----------------------------------------------------------------------------- documents


def _round(x, digits: int):
    if isinstance(x, dict):
        return {k: _round(x[k], digits) for k in sorted(x)}
    if isinstance(x, (list, tuple)):
        return [_round(v, digits) for v in x]
    if isinstance(x, float):
        return float(f"{x:.{digits}g}")
    return x


def gltf_document(exports, digits: int = DOCUMENT_DIGITS) -> dict:
    """A minimal glTF 2.0 document holding the exports' materials (in the given order):
    ``asset`` (version 2.0, generator ``brdf_fit <version>``), ``materials`` and
    ``extensionsUsed`` (their sorted union, omitted when empty). Floats are rounded to
    ``digits`` significant digits and keys sorted, so the output is deterministic; write it with
    :func:`write_gltf` (or ``json.dump(..., sort_keys=True)``)."""
    mats = [e.material if isinstance(e, GltfExport) else e for e in exports]
    used = sorted({x for m in mats for x in (m.get("extensions") or {})})
    doc = {"asset": {"generator": f"brdf_fit {__version__}", "version": "2.0"},
           "materials": [_round(m, digits) for m in mats]}
    if used:
        doc["extensionsUsed"] = used
    return doc


def write_gltf(path, exports_or_document, digits: int = DOCUMENT_DIGITS) -> None:
    """Write :func:`gltf_document` of the exports (or a document) as JSON (sorted keys),
    whole or not at all (:mod:`brdf_fit.core.atomic`)."""
    doc = exports_or_document
    if not isinstance(doc, dict):
        doc = gltf_document(doc, digits)
    write_text_atomic(path, json.dumps(doc, indent=2, sort_keys=True) + "\n")


def _is_num(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _check_material(m, where: str) -> None:
    def bad(msg):
        raise ExportError(f"{where}: {msg}")

    if not isinstance(m, dict):
        bad(f"must be a JSON object, got {type(m).__name__}")
    if "name" in m and not isinstance(m["name"], str):
        bad("name must be a string")
    pbr = m.get("pbrMetallicRoughness", {})
    if not isinstance(pbr, dict):
        bad("pbrMetallicRoughness must be an object")
    bc = pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0])
    if not (isinstance(bc, list) and len(bc) == 4 and all(_is_num(v) and 0 <= v <= 1 for v in bc)):
        bad(f"baseColorFactor must be 4 numbers in [0, 1], got {json.dumps(bc)}")
    for key in ("metallicFactor", "roughnessFactor"):
        v = pbr.get(key, 1.0)
        if not (_is_num(v) and 0 <= v <= 1):
            bad(f"{key} must be a number in [0, 1], got {json.dumps(v)}")
    ext = m.get("extensions", {})
    if not isinstance(ext, dict):
        bad("extensions must be an object")
    spec = ext.get("KHR_materials_specular", {})
    if not isinstance(spec, dict):
        bad("KHR_materials_specular must be an object")
    sf = spec.get("specularFactor", 1.0)
    if not (_is_num(sf) and 0 <= sf <= 1):
        bad(f"KHR_materials_specular.specularFactor must be a number in [0, 1], got "
            f"{json.dumps(sf)}")
    sc = spec.get("specularColorFactor", [1.0, 1.0, 1.0])
    if not (isinstance(sc, list) and len(sc) == 3 and all(_is_num(v) and v >= 0 for v in sc)):
        bad(f"KHR_materials_specular.specularColorFactor must be 3 numbers >= 0, got "
            f"{json.dumps(sc)}")
    ior_ext = ext.get("KHR_materials_ior", {})
    if not isinstance(ior_ext, dict):
        bad("KHR_materials_ior must be an object")
    ior = ior_ext.get("ior", 1.5)
    if not (_is_num(ior) and (ior == 0 or ior >= 1)):
        bad(f"KHR_materials_ior.ior must be 0 or >= 1, got {json.dumps(ior)}")


def read_gltf_materials(path) -> list[tuple[str, dict]]:
    """The materials of a glTF 2.0 JSON file as ``(name, material)`` pairs (``name`` defaults to
    ``material_<index>``), checked against the specification's material rules (those
    :func:`appendix_b_eval` relies on). Any problem is a one-line :class:`ExportError` naming the
    file and, for a material, its index: not JSON, no ``asset.version``, an unsupported required
    extension, ``baseColorFactor`` not 4 numbers in [0, 1], ``metallicFactor`` or
    ``roughnessFactor`` outside [0, 1], an invalid ``KHR_materials_specular`` or
    ``KHR_materials_ior``. ``.glb`` (binary) files are not read."""
    p = os.fspath(path)
    try:
        with open(p, encoding="utf-8") as fh:
            doc = json.load(fh)
    except OSError as e:
        raise ExportError(f"{p}: cannot read: {e.strerror or e}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        msg = str(e).splitlines()[0]
        raise ExportError(f"{p}: not a glTF JSON file: {msg}") from None
    if not isinstance(doc, dict):
        raise ExportError(f"{p}: not a glTF document (the top level is not a JSON object)")
    asset = doc.get("asset")
    version = asset.get("version") if isinstance(asset, dict) else None
    if not isinstance(version, str) or not _VERSION_RE.match(version):
        raise ExportError(f"{p}: asset.version is missing or not 'major.minor' (got "
                          f"{json.dumps(version)})")
    if not version.startswith("2."):
        raise ExportError(f"{p}: glTF version {version} is not supported (2.x is)")
    mats = doc.get("materials", [])
    if not isinstance(mats, list):
        raise ExportError(f"{p}: materials must be an array")
    required = doc.get("extensionsRequired", [])
    if not isinstance(required, list):
        raise ExportError(f"{p}: extensionsRequired must be an array")
    for x in required:
        if x not in SUPPORTED_EXTENSIONS:
            users = [i for i, m in enumerate(mats) if isinstance(m, dict)
                     and x in (m.get("extensions") or {})]
            where = f"materials[{users[0]}]" if users else "document"
            raise ExportError(f"{p}: {where}: unsupported required extension {x!r} (supported: "
                              f"{', '.join(SUPPORTED_EXTENSIONS)})")
    out = []
    for i, m in enumerate(mats):
        _check_material(m, f"{p}: materials[{i}]")
        out.append((m.get("name", f"material_{i}"), m))
    return out
