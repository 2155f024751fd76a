"""Export a registry model as a Mitsuba 3 BSDF, with the semantic difference measured in Mitsuba.

Mitsuba 3 is optional: it is imported inside the functions that need it (:func:`mitsuba_eval`,
and the round trip in :func:`to_mitsuba`); without it an export is built, its ``error`` is None
and its note says "not verified: mitsuba not installed". Evaluation uses the ``scalar_rgb``
variant (float32; no LLVM needed); the variant that was active before is restored afterwards.

Conventions (Mitsuba 3 ``BSDF.eval``): in the local frame, ``si.wi`` points toward the viewer
(our ``wo``) and the ``wo`` argument toward the light (our ``wi``); the result is
``f cos(theta)`` of that argument, so :func:`mitsuba_eval` divides by ``wi.z``. Mitsuba takes
``alpha`` (the microfacet width), not perceptual roughness, except ``principled`` (``roughness``,
``alpha = roughness^2``). RGB reflectances (``rgb`` in a dict) must lie in [0, 1]: Mitsuba
refuses larger values; an ``srgb`` texture with ``unbounded`` true, or a ``uniform`` spectrum,
carries a larger one.

Semantics, measured against this package's models with Mitsuba 3.9.1 from PyPI
(``tests/convert/test_mitsuba_export.py`` holds each):

* ``diffuse``: ``reflectance / pi``: Lambert exactly.
* ``roughconductor`` (``distribution`` ggx or beckmann; its default is beckmann): microfacet
  D with the **separable** Smith G (for Beckmann Walter et al. 2007's rational G1), the exact
  conductor Fresnel of ``eta + i k`` at ``wi.h``, times ``specular_reflectance``. It equals our
  ``GGX``/``Beckmann(lambda_approx="walter")`` + ``SmithSeparable`` + ``ConductorFresnel`` to
  float32 rounding.
* ``principled`` with ``metallic = 1``: GGX, separable Smith G, Schlick Fresnel with
  ``F0 = base_color``: our ``ggx-separable`` to float32 rounding.
* ``roughplastic`` is not "Lambert + GGX, summed" (formats.md section 3): it is measured as a
  candidate for ``ggx-plastic`` and loses.

Mappings (:data:`MAPPINGS`; the candidates of each are measured by round trip and the one with
the smallest error is exported; without Mitsuba the first, the predicted best, is):

* ``lambert`` -> ``diffuse`` (exact).
* ``ggx-conductor`` -> ``roughconductor`` ggx, same ``alpha``, ``eta``, ``k`` (approximate:
  Mitsuba's separable G against our height-correlated G, a difference that grows toward grazing).
* ``ggx`` -> ``principled`` metallic 1, ``base_color = f0``, ``roughness = sqrt(alpha)``
  (approximate: separable G), or ``roughconductor`` ggx with ``(eta, k)`` per channel chosen
  with ``F(1) = f0`` kept, either to match the Schlick curve (``roughconductor-schlick``,
  :func:`schlick_conductor_ior`) or to match the model's values on the geometry
  (``roughconductor-fit``, :func:`fitted_conductor_ior`; approximate: separable G and the
  exact conductor Fresnel).
* ``ggx-separable`` -> the same candidates; ``principled`` is exact.
* ``beckmann`` / ``beckmann-walter`` -> ``roughconductor`` beckmann with either ``(eta, k)``
  (approximate: the Fresnel curve, and for ``beckmann`` the rational separable G1).
* ``ggx-conductor-aniso`` -> ``roughconductor`` ggx with ``alpha_u = alpha_x`` (the tangent)
  and ``alpha_v = alpha_y``; ``ggx-aniso`` -> the two fitted-Fresnel ``roughconductor``
  candidates at those widths (approximate, as their isotropic forms).
* ``ggx-plastic`` (``rho_d/pi`` + GGX with Schlick ``f0``, summed) -> ``blendbsdf`` of weight
  0.5 (``0.5 A + 0.5 B``) of ``diffuse`` with reflectance ``2 rho_d`` (an unbounded ``srgb``
  texture where ``2 rho_d > 1``) and ``roughconductor`` ggx with ``specular_reflectance`` 2 (a
  ``uniform`` spectrum) and ``(eta, k)`` fitted to the specular lobe on the geometry: the sum
  written as a blend (approximate: separable G and the Fresnel curve); ``roughplastic``
  (``diffuse_reflectance = rho_d``, ``int_ior`` from ``f0``) is measured as the other candidate.

Measured errors at default parameters on the default geometry (Mitsuba 3.9.1): lambert 1.8e-8
(float32), ggx-separable 3.1e-7, ggx-conductor 1.93e-2, ggx 4.20e-2 (principled; the
``roughconductor`` candidates 0.105 / 0.114), ggx-plastic 5.78e-2 (``roughplastic`` 0.105),
beckmann 8.75e-2, beckmann-walter 8.64e-2, ggx-conductor-aniso 1.17e-3, ggx-aniso 5.29e-2
(``roughconductor-fit``; ``-schlick`` 5.91e-2). For a Schlick-Fresnel source, exporting from a
``ggx-separable`` fit is exact.

Any other model raises :class:`ExportError` naming it (export it to glTF, fitted, instead).
"""

from __future__ import annotations

import dataclasses
import math
from xml.sax.saxutils import quoteattr

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit.convert.gltf import (
    ERROR_MEASURE,
    ExportError,
    default_geometry,
    export_source,
    lobe_width,
    radiance_error,
    source_rgb,
)
from brdf_fit.core.fresnel import ConductorFresnel, conductor, ior_from_f0, schlick
from brdf_fit.core.microfacet import GGX, Beckmann, SmithSeparable
from brdf_fit.core.numerics import INV_PI
from brdf_fit.models.microfacet_brdf import MicrofacetBRDF
from brdf_fit.models.mitsuba import MITSUBA_VERSION

__all__ = [
    "MITSUBA_EXTRA",
    "VARIANT",
    "MAPPINGS",
    "MAX_MITSUBA_SAMPLES",
    "GRAZING_DEG",
    "ExportError",
    "MitsubaExport",
    "mitsuba_eval",
    "schlick_conductor_ior",
    "fitted_conductor_ior",
    "separable_conductor",
    "to_mitsuba",
    "scene_dict_to_xml",
    "scene_document",
    "xml_comment",
]

#: the optional extra that installs Mitsuba (``pip install brdf_fit[mitsuba]``)
MITSUBA_EXTRA = "mitsuba"
#: the smallest f0 a roughplastic is written with: Mitsuba refuses int_ior = ext_ior, which a
#: fitted f0 at its bound 0 gives (a coat that reflects nothing); 1e-8 is int_ior 1.0002
ROUGHPLASTIC_F0_MIN = 1e-8
#: the Mitsuba variant the round trip uses
VARIANT = "scalar_rgb"
#: the round trip evaluates Mitsuba one direction pair at a time (scalar variant): the default
#: geometry is thinned to at most this many pairs (every k-th pair)
MAX_MITSUBA_SAMPLES = 400
#: zenith (degrees) from which a pair counts as grazing in ``MitsubaExport.error_grazing``
GRAZING_DEG = 60.0
#: model -> candidate plugins, the predicted best first (module docstring)
MAPPINGS = {
    "lambert": ("diffuse",),
    "ggx-conductor": ("roughconductor",),
    "ggx": ("principled", "roughconductor-fit", "roughconductor-schlick"),
    "ggx-separable": ("principled", "roughconductor-fit", "roughconductor-schlick"),
    "beckmann": ("roughconductor-fit", "roughconductor-schlick"),
    "beckmann-walter": ("roughconductor-fit", "roughconductor-schlick"),
    "ggx-plastic": ("blendbsdf", "roughplastic"),
    # the anisotropic candidates selection adds when the data show anisotropy: Mitsuba's
    # roughconductor takes alpha_u (along the tangent, our x) and alpha_v
    "ggx-conductor-aniso": ("roughconductor",),
    "ggx-aniso": ("roughconductor-fit", "roughconductor-schlick"),
}
_EXACT = {("lambert", "diffuse"), ("ggx-separable", "principled")}
_NOTES = {
    "diffuse": "Mitsuba diffuse is reflectance/pi: the same BRDF",
    "roughconductor": ("Mitsuba roughconductor uses the separable Smith G where the model has "
                       "the height-correlated one: slightly darker toward grazing"),
    "principled": ("Mitsuba principled with metallic 1 is GGX, separable Smith G, Schlick "
                   "F0 = base_color; roughness = sqrt(alpha)"),
    "roughconductor-schlick": ("Mitsuba roughconductor has the exact conductor Fresnel, not "
                               "Schlick: (eta, k) per channel fitted to the Schlick curve with "
                               "F(0) = f0 kept; its G is separable"),
    "roughconductor-fit": ("Mitsuba roughconductor has the exact conductor Fresnel, not "
                           "Schlick, and separable G: (eta, k) per channel fitted to the "
                           "model's values on the geometry with F(0) = f0 kept"),
    "blendbsdf": ("the sum rho_d/pi + specular written as blendbsdf 0.5 (2 rho_d diffuse) + "
                  "0.5 (roughconductor x2, (eta, k) fitted to the specular lobe on the "
                  "geometry with F(0) = f0 kept); separable G"),
    "roughplastic": ("Mitsuba roughplastic couples the diffuse layer to the coating "
                     "(transmittance, internal reflection): not the summed model"),
}


@dataclasses.dataclass
class MitsubaExport:
    """Outcome of :func:`to_mitsuba`.

    ``plugin``: the chosen candidate; ``scene_dict``: a ``mi.load_dict``-able dict;
    ``xml``: the same as a Mitsuba 3 XML ``<bsdf>`` element (``version="3.0.0"``, loadable with
    ``mi.load_string``; drop the ``version`` attribute when pasting it into a ``<scene>``);
    ``method``: "exact" or "approximate"; ``note``: the semantic difference in one line;
    ``error``: :data:`ERROR_MEASURE` measured by round trip through Mitsuba (None when Mitsuba
    is not installed); ``candidates``: each candidate's measured error; ``geometry``: a sentence;
    ``n_samples``: direction pairs measured; ``error_grazing`` / ``error_non_grazing``: the
    error split at :data:`GRAZING_DEG`."""

    source: str
    params: dict
    plugin: str
    scene_dict: dict
    xml: str
    method: str
    note: str
    error: float | None
    candidates: dict
    geometry: str
    n_samples: int
    #: the same measure over the pairs with a zenith (either direction) of at least
    #: :data:`GRAZING_DEG`, and over the rest: where the semantic difference sits
    error_grazing: float | None = None
    error_non_grazing: float | None = None

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["params"] = {k: np.asarray(v).tolist() for k, v in self.params.items()}
        d["error_measure"] = ERROR_MEASURE
        return d


# ----------------------------------------------------------------------------- Mitsuba


def _mitsuba():
    """The ``mitsuba`` module, or None when it is not installed."""
    try:
        import mitsuba as mi
    except ImportError:
        return None
    return mi


def mitsuba_eval(scene_dict: dict, wi, wo) -> np.ndarray:
    """Evaluate the Mitsuba BSDF ``scene_dict`` at our ``(N, 3)`` directions (``wi`` toward the
    light, ``wo`` toward the viewer, local frame z = normal): ``(N, 3)`` values of f in 1/sr
    (Mitsuba's ``f cos`` divided by ``wi.z``; 0 where a direction is below the surface). One
    scalar evaluation per pair (keep N to a few hundred). Raises ImportError without Mitsuba."""
    mi = _mitsuba()
    if mi is None:
        raise ImportError("mitsuba is not installed (pip install brdf_fit[mitsuba])")
    wi = np.asarray(wi, float)
    wo = np.asarray(wo, float)
    prev = mi.variant()
    mi.set_variant(VARIANT)
    try:
        bsdf = mi.load_dict(scene_dict)
        ctx = mi.BSDFContext()
        frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
        out = np.zeros((wi.shape[0], 3))
        for n in range(wi.shape[0]):
            if wi[n, 2] <= 0.0 or wo[n, 2] <= 0.0:
                continue
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*(float(x) for x in wo[n]))
            si.sh_frame = frame
            v = bsdf.eval(ctx, si, mi.Vector3f(*(float(x) for x in wi[n])))
            out[n] = [float(v[0]), float(v[1]), float(v[2])]
        out /= np.where(wi[:, 2:3] > 0.0, wi[:, 2:3], 1.0)
    finally:
        if prev is not None and prev != VARIANT:
            mi.set_variant(prev)
    return out


# ----------------------------------------------------------------------------- Schlick -> (eta, k)

#: cos grid on which the conductor Fresnel is matched to the Schlick curve
_FRESNEL_COS = np.linspace(0.0, 1.0, 129)
#: candidate extinction coefficients, as fractions of the largest k that keeps F(0) = f0
_K_FRACTIONS = np.linspace(0.0, 1.0, 401)


def schlick_conductor_ior(f0):
    """``(eta, k)`` per channel whose exact conductor Fresnel best matches Schlick's
    ``f0 + (1 - f0)(1 - c)^5`` (least squares on 129 uniform ``c`` in [0, 1]) while keeping
    ``F(1) = f0`` exactly: for each ``k`` on a 401-point grid in ``[0, k_max(f0)]`` both roots
    ``eta`` of ``((eta - 1)^2 + k^2)/((eta + 1)^2 + k^2) = f0`` are tried. ``f0`` is clipped to
    [1e-6, 0.999]. Returns two float64 arrays of ``f0``'s shape."""
    f0a = np.atleast_1d(np.asarray(f0, float))
    etas, ks = [], []
    c = _FRESNEL_COS
    for f in f0a.ravel():
        eta, kk = _f0_roots(f)
        with jax.enable_x64(True):
            F = np.asarray(conductor(jnp.asarray(c)[None, :], jnp.asarray(eta)[:, None],
                                     jnp.asarray(kk)[:, None]))
            S = np.asarray(schlick(jnp.asarray(c), min(max(float(f), 1e-6), 0.999)))
        j = int(np.argmin(np.mean((F - S[None, :]) ** 2, axis=1)))
        etas.append(eta[j])
        ks.append(kk[j])
    shape = np.shape(np.asarray(f0))
    return np.asarray(etas).reshape(shape), np.asarray(ks).reshape(shape)


def _f0_roots(f):
    """``(eta, k)`` candidates with normal-incidence reflectance ``f`` (both roots, k grid)."""
    f = min(max(float(f), 1e-6), 0.999)
    kmax = math.sqrt(max(((1.0 + f) / (1.0 - f)) ** 2 - 1.0, 0.0))
    k = _K_FRACTIONS * kmax
    disc = np.sqrt(np.maximum((1.0 + f) ** 2 - (1.0 - f) ** 2 * (1.0 + k * k), 0.0))
    eta = np.concatenate([((1.0 + f) + disc) / (1.0 - f), ((1.0 + f) - disc) / (1.0 - f)])
    kk = np.concatenate([k, k])
    ok = eta > 1e-6
    return eta[ok], kk[ok]


def separable_conductor(alpha, eta, k, distribution: str = "ggx",
                        alpha_v=None) -> MicrofacetBRDF:
    """Mitsuba 3 ``roughconductor``'s semantics as a model of this package: GGX or Beckmann
    with Walter's rational G1 (Mitsuba's ``smith_g1``), separable Smith G, the exact conductor
    Fresnel (module docstring; held against Mitsuba by the tests). ``alpha_v``: the width along
    the bitangent when anisotropic (``alpha`` is then Mitsuba's ``alpha_u``)."""
    dist = (GGX(alpha, alpha_v) if distribution == "ggx"
            else Beckmann(alpha, alpha_v, lambda_approx="walter"))
    return MicrofacetBRDF(distribution=dist, masking=SmithSeparable(),
                          fresnel=ConductorFresnel(eta, k))


def fitted_conductor_ior(target, wi, wo, alpha, f0, distribution: str = "ggx",
                         alpha_v=None):
    """``(eta, k)`` per channel for a ``roughconductor`` whose predicted values
    (:func:`separable_conductor`) best match ``target`` (``(N, 3)``, e.g. a Schlick-Fresnel
    lobe) in the cos-weighted radiance least squares on ``(wi, wo)``, keeping ``F(1) = f0``:
    the :func:`schlick_conductor_ior` search, scored on the geometry instead of the Fresnel
    curve, so it also absorbs part of the masking difference."""
    target = np.asarray(target, float)
    f0 = np.broadcast_to(np.asarray(f0, float), (3,))
    c = np.asarray(wi, float)[:, 2:3]
    etas, ks = np.zeros(3), np.zeros(3)
    with jax.enable_x64(True):
        wij, woj = jnp.asarray(wi, float), jnp.asarray(wo, float)
        for ch in range(3):
            eta, kk = _f0_roots(f0[ch])
            f = np.asarray(separable_conductor(alpha, jnp.asarray(eta), jnp.asarray(kk),
                                               distribution, alpha_v).eval(wij, woj))
            score = np.sum(((f - target[:, ch:ch + 1]) * c) ** 2, axis=0)
            j = int(np.argmin(score))
            etas[ch], ks[ch] = eta[j], kk[j]
    return etas, ks


# ----------------------------------------------------------------------------- candidates


def _rgb(v) -> dict:
    v = [float(x) for x in np.broadcast_to(np.asarray(v, float), (3,))]
    if all(0.0 <= x <= 1.0 for x in v):
        return {"type": "rgb", "value": v}
    return {"type": "srgb", "color": v, "unbounded": True}


def _param_rgb(v) -> dict:
    """An unbounded RGB parameter (eta, k): Mitsuba accepts any value there."""
    return {"type": "rgb", "value": [float(x) for x in np.broadcast_to(np.asarray(v, float),
                                                                         (3,))]}


def _candidate(kind: str, model: str, p: dict, geometry=None) -> dict:
    """The scene dict of candidate ``kind`` for ``model`` at RGB parameters ``p``;
    ``geometry = (wi, wo, target)`` (the source's specular values) for the ``-fit`` kinds and
    ``blendbsdf``."""
    dist = "beckmann" if model.startswith("beckmann") else "ggx"
    # Mitsuba's widths: ``alpha``, or ``alpha_u`` (tangent, our x) and ``alpha_v``
    if "alpha_x" in p:
        au, av = float(p["alpha_x"]), float(p["alpha_y"])
        widths = {"alpha_u": au, "alpha_v": av}
    else:
        au, av = (float(p["alpha"]) if "alpha" in p else None), None
        widths = {"alpha": au}
    if kind == "diffuse":
        return {"type": "diffuse", "reflectance": _rgb(p["rho"])}
    if kind == "roughconductor":
        return {"type": "roughconductor", "distribution": "ggx", **widths,
                "eta": _param_rgb(p["eta"]), "k": _param_rgb(p["k"])}
    if kind == "principled":
        return {"type": "principled", "base_color": _rgb(p["f0"]), "metallic": 1.0,
                "roughness": math.sqrt(float(p["alpha"]))}
    if kind in ("roughconductor-schlick", "roughconductor-fit", "blendbsdf"):
        f0 = np.broadcast_to(np.asarray(p["f0"], float), (3,))
        if kind == "roughconductor-schlick":
            eta, k = schlick_conductor_ior(f0)
        else:
            wi, wo, target = geometry
            eta, k = fitted_conductor_ior(target, wi, wo, au, f0, dist, av)
        lobe = {"type": "roughconductor", "distribution": dist, **widths,
                "eta": _param_rgb(eta), "k": _param_rgb(k)}
        if kind != "blendbsdf":
            return lobe
        lobe["specular_reflectance"] = {"type": "uniform", "value": 2.0}
        return {"type": "blendbsdf", "weight": 0.5,
                "bsdf_0": {"type": "diffuse", "reflectance": _rgb(2.0 * np.asarray(p["rho_d"]))},
                "bsdf_1": lobe}
    if kind == "roughplastic":
        return {"type": "roughplastic", "distribution": "ggx", "alpha": float(p["alpha"]),
                "diffuse_reflectance": _rgb(p["rho_d"]),
                "int_ior": float(ior_from_f0(min(max(float(np.max(p["f0"])), ROUGHPLASTIC_F0_MIN),
                                                 0.999))),
                "ext_ior": 1.0}
    raise AssertionError(kind)


# ----------------------------------------------------------------------------- XML

_BSDF_KEYS = ("bsdf_0", "bsdf_1", "bsdf")


def _fmt(x: float) -> str:
    return repr(float(x))


def _xml_value(key: str, v, indent: str) -> list[str]:
    a = quoteattr(key)
    if isinstance(v, bool):
        return [f'{indent}<boolean name={a} value="{str(v).lower()}"/>']
    if isinstance(v, (int, float)):
        return [f"{indent}<float name={a} value={quoteattr(_fmt(v))}/>"]
    if isinstance(v, str):
        return [f"{indent}<string name={a} value={quoteattr(v)}/>"]
    if isinstance(v, dict):
        t = v.get("type")
        if t == "rgb":
            vals = ", ".join(_fmt(x) for x in v["value"])
            return [f"{indent}<rgb name={a} value={quoteattr(vals)}/>"]
        if t == "uniform":
            return [f"{indent}<spectrum name={a} value={quoteattr(_fmt(v['value']))}/>"]
        if t == "srgb":
            vals = ", ".join(_fmt(x) for x in v["color"])
            lines = [f'{indent}<texture type="srgb" name={a}>',
                     f'{indent}  <rgb name="color" value={quoteattr(vals)}/>']
            if v.get("unbounded"):
                lines.append(f'{indent}  <boolean name="unbounded" value="true"/>')
            return lines + [f"{indent}</texture>"]
        return _xml_bsdf(v, indent, name=key)
    raise ExportError(f"cannot write {key!r} = {v!r} as Mitsuba XML")


def _xml_bsdf(d: dict, indent: str, name: str | None = None, bsdf_id: str | None = None,
              version: str | None = None) -> list[str]:
    attrs = [f"type={quoteattr(d['type'])}"]
    if bsdf_id is not None:
        attrs.append(f"id={quoteattr(bsdf_id)}")
    if name is not None:
        attrs.append(f"name={quoteattr(name)}")
    if version is not None:
        attrs.insert(0, f"version={quoteattr(version)}")
    lines = [f"{indent}<bsdf {' '.join(attrs)}>"]
    for key in sorted(k for k in d if k != "type"):
        lines += _xml_value(key, d[key], indent + "  ")
    return lines + [f"{indent}</bsdf>"]


def xml_comment(text: str) -> str:
    """``<!-- text -->`` that XML allows: a comment may not contain ``--`` nor end in ``-``
    (XML 1.0, production [15]); each ``--`` becomes ``- -``."""
    t = str(text)
    while "--" in t:
        t = t.replace("--", "- -")
    if t.endswith("-"):
        t += " "
    return f"<!-- {t} -->"


def scene_document(bsdfs: list[tuple[str, dict]], comment: str | None = None) -> str:
    """A Mitsuba 3 XML ``<scene>`` holding one ``<bsdf id=...>`` per ``(id, scene_dict)``,
    well-formed XML (``xml.etree`` parses it; ``mi.load_string`` loads it)."""
    parts = [scene_dict_to_xml(d, bsdf_id=i, version=None) for i, d in bsdfs]
    return ('<?xml version="1.0" encoding="utf-8"?>\n'
            + ("" if comment is None else xml_comment(comment) + "\n")
            + '<scene version="3.0.0">\n'
            + "".join("    " + ln + "\n" for p in parts for ln in p.strip().splitlines())
            + "</scene>\n")


def scene_dict_to_xml(scene_dict: dict, bsdf_id: str | None = None,
                      version: str = "3.0.0") -> str:
    """A Mitsuba 3 XML ``<bsdf>`` element of ``scene_dict`` (the dict forms this module writes:
    numbers, strings, booleans, ``rgb``, ``uniform``, ``srgb`` textures and nested BSDFs)."""
    return "\n".join(_xml_bsdf(scene_dict, "", bsdf_id=bsdf_id, version=version)) + "\n"


# ----------------------------------------------------------------------------- export


def _rgb_params(entry_name: str, full: dict) -> dict:
    out = {}
    for k, v in full.items():
        a = np.asarray(v, float)
        if a.ndim == 1 and a.shape[0] not in (1, 3):
            raise ExportError(f"cannot export {entry_name!r} to Mitsuba: parameter {k!r} has "
                              f"{a.shape[0]} channels; the {VARIANT} variant takes RGB")
        out[k] = a if a.ndim == 0 else np.broadcast_to(a, (3,))
    return out


def to_mitsuba(model_name: str, params: dict | None = None, *, name: str | None = None,
               geometry=None, verify: bool = True) -> MitsubaExport:
    """Export registry model ``model_name`` at ``params`` (defaults for the rest) as a Mitsuba 3
    BSDF (module docstring: mappings, candidates, semantics). With Mitsuba installed (and
    ``verify``) every candidate is evaluated in Mitsuba on the geometry (``(wi, wo)`` arrays;
    default :func:`brdf_fit.convert.gltf.default_geometry` at the source's width, thinned to
    :data:`MAX_MITSUBA_SAMPLES`) and the one with the smallest :data:`ERROR_MEASURE` is kept.
    Models without a mapping raise :class:`ExportError`."""
    entry, model, full = export_source(model_name, params)
    native = entry.target == "mitsuba"
    if not native and entry.name not in MAPPINGS:
        raise ExportError(
            f"cannot export {entry.name!r} to Mitsuba 3: no plugin with its semantics is mapped "
            f"(mapped: {', '.join(MAPPINGS)}, and the native mitsuba-* entries); fit with "
            "--target mitsuba, or export it to glTF (fitted)")
    p = _rgb_params(entry.name, full)
    name = entry.name if name is None else str(name)
    if geometry is None:
        wi, wo, text = default_geometry(lobe_width(full))
        step = max(1, math.ceil(wi.shape[0] / MAX_MITSUBA_SAMPLES))
        wi, wo = wi[::step], wo[::step]
        text = f"{text}; every {step}th pair kept: {wi.shape[0]} pairs"
    else:
        wi, wo = (np.asarray(g, float) for g in geometry)
        text = f"user geometry: {wi.shape[0]} direction pairs"
    f_src = source_rgb(model, wi, wo, entry.name)
    if native:
        d_native = entry.native_export(p)
        kinds = (d_native["type"],)
        dicts = {d_native["type"]: d_native}
    else:
        kinds = MAPPINGS[entry.name]
        target = f_src - (np.asarray(p["rho_d"]) * INV_PI if "rho_d" in p else 0.0)
        dicts = {k: _candidate(k, entry.name, p, (wi, wo, target)) for k in kinds}
    mi = _mitsuba() if verify else None
    errors: dict = {}
    split = [None, None]
    if mi is not None:
        values = {k: mitsuba_eval(d, wi, wo) for k, d in dicts.items()}
        for k in kinds:
            errors[k] = radiance_error(f_src, values[k], wi)
        best = min(kinds, key=lambda k: errors[k])
        error = errors[best]
        cz = math.cos(math.radians(GRAZING_DEG))
        grazing = np.minimum(wi[:, 2], wo[:, 2]) <= cz
        for j, sel in enumerate((grazing, ~grazing)):
            if np.any(sel):
                split[j] = radiance_error(f_src[sel], values[best][sel], wi[sel])
        verified = (f"measured in Mitsuba {mi.__version__} ({VARIANT}, float32); error "
                    f"{error:.3g}, {split[0] if split[0] is None else format(split[0], '.3g')} "
                    f"where a zenith >= {GRAZING_DEG:g} deg, "
                    f"{split[1] if split[1] is None else format(split[1], '.3g')} elsewhere")
    else:
        best = kinds[0]
        error = None
        verified = ("not verified: mitsuba not installed" if verify else
                    "not verified: verify=False")
    exact = native or (entry.name, best) in _EXACT
    note = (f"native entry: Mitsuba's {best} plugin itself, every parameter written as fitted "
            f"(brdf_fit.models.mitsuba, checked against Mitsuba {MITSUBA_VERSION}); {verified}"
            if native else f"{_NOTES[best]}; {verified}")
    if len(kinds) > 1 and errors:
        note += "; candidates: " + ", ".join(f"{k} {errors[k]:.3g}" for k in kinds)
    d = dicts[best]
    return MitsubaExport(source=entry.name, params=full, plugin=best, scene_dict=d,
                         xml=scene_dict_to_xml(d, bsdf_id=name),
                         method="exact" if exact else "approximate", note=note, error=error,
                         candidates=errors, geometry=text, n_samples=int(wi.shape[0]),
                         error_grazing=split[0], error_non_grazing=split[1])

