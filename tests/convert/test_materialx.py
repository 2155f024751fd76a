"""MaterialX export (brdf_fit.convert.materialx) and the parity of the OpenPBR entries with
MaterialX's own GLSL (brdf_fit.convert.materialx_render: the exported document's shader, made by
MaterialX's generator, run on an OpenGL context).

Without the ``materialx`` package the validation tests skip, and without ``moderngl`` or an EGL
OpenGL context the render tests skip, each with one line; the document's own tests always run."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import jax
import numpy as np
import pytest

from brdf_fit.convert import materialx as cx
from brdf_fit.convert import materialx_render as mr
from brdf_fit.models import _materialx as mxf
from brdf_fit.models.openpbr import OpenPBRSurface
from tests._helpers import float32_spread, grazing_pairs, parity_pairs

jax.config.update("jax_enable_x64", True)

#: materials of the parity tests: each entry's lobes and the class's other inputs
MATERIALS = {
    "dielectric": ("openpbr-surface", {"base_color": (0.8, 0.1, 0.05),
                                       "specular_roughness": 0.35}),
    "metal": ("openpbr-surface", {"base_color": (0.9, 0.6, 0.3), "base_metalness": 1.0,
                                  "specular_roughness": 0.5, "specular_color": (0.8, 0.9, 1.0)}),
    "mixed": ("openpbr-surface", {"base_color": (0.5, 0.4, 0.2), "base_metalness": 0.4,
                                  "specular_roughness": 0.2, "specular_ior": 1.8}),
    "aniso": ("openpbr-surface-aniso", {"base_color": (0.9, 0.6, 0.3), "base_metalness": 1.0,
                                        "specular_roughness": 0.4,
                                        "specular_roughness_anisotropy": 0.7}),
    "coat": ("openpbr-surface-coat", {"base_color": (0.6, 0.2, 0.1), "coat_weight": 0.8,
                                      "coat_roughness": 0.1, "coat_ior": 1.5,
                                      "specular_roughness": 0.4}),
    "tinted_coat": ("openpbr-surface-coat", {"base_color": (0.6, 0.2, 0.1), "coat_weight": 0.6,
                                             "coat_roughness": 0.3, "base_metalness": 0.3,
                                             "coat_color": (0.9, 0.8, 0.5),
                                             "coat_darkening": 0.5,
                                             "coat_roughness_anisotropy": 0.4}),
    "fuzz": ("openpbr-surface-fuzz", {"base_color": (0.3, 0.3, 0.6), "fuzz_weight": 0.7,
                                      "fuzz_roughness": 0.4, "fuzz_color": (1.0, 0.8, 0.8)}),
    "rough_diffuse": ("openpbr-surface", {"base_color": (0.7, 0.5, 0.3),
                                          "base_diffuse_roughness": 0.6, "base_weight": 0.8,
                                          "specular_weight": 0.6,
                                          "specular_color": (0.9, 0.9, 0.7)}),
}
#: the parity's relative bound: MaterialX's float32 GLSL against this float64 model. Measured
#: (llvmpipe, 2026-12-07): at most 7.6e-6 at random pairs over the materials above but the rough
#: diffuse, whose lobe reads llvmpipe's acos (:func:`_acos_bound`); this model's own float32
#: evaluation differs from its float64 by up to 2.7e-6 there, and llvmpipe's pow by 1.6e-6
#: relative. Larger where the value itself is ill-conditioned in float32 (grazing near-mirror
#: pairs: :data:`SPREAD_FACTOR`)
PARITY_REL = 2e-5
#: how many times the model's float32 spread (:func:`~tests._helpers.float32_spread`, the
#: directions moved by :data:`ROUNDINGS` float32 epsilons and its own float32 arithmetic) the
#: parity allows beside PARITY_REL
SPREAD_FACTOR = 8.0
#: the directions reach MaterialX's shader through a rotation to world space (float64, then
#: float32 vertex data) and the shader's normalisations: a few roundings each
ROUNDINGS = 4.0
#: the world frame's turns about the light (radians) at which each pair is rendered: the
#: renderer's own float32 rounding differs from turn to turn, and its spread over them is
#: allowed :data:`RENDER_SPREAD_FACTOR` times. Measured: up to 6.1e-4 relative at the coat's
#: grazing near-mirror pair (cos 0.01 and 0.02, opposite azimuths; alpha 0.01), where MaterialX
#: forms the half vector from nearly opposite directions, and that pair differed from this
#: model by 5.9e-4; at most 2e-6 away from grazing
SPINS = (0.0, 1.0, 2.0, 3.0, 4.0)
RENDER_SPREAD_FACTOR = 2.0
#: the parity's absolute floor: f cos below this is float32 noise around 0 (grazing light)
PARITY_ABS = 1e-9


def _render_or_skip():
    try:
        mr.glsl_error("sqrt", 0.0, 1.0, np.sqrt, n=16)
    except mr.MaterialXRenderUnavailable as exc:
        pytest.skip(str(exc))


def _materialx_or_skip():
    pytest.importorskip("MaterialX", reason=cx.MATERIALX_EXTRA)


def _document(name, entry, params):
    return cx.mtlx_document([cx.to_materialx(entry, params, name)])


def _model(entry, params):
    from brdf_fit import registry

    full = {**registry.get(entry).defaults(), **params}
    return OpenPBRSurface(**{k: np.asarray(v, np.float64) for k, v in full.items()})


def _acos_bound(params, wi, wo, delta):
    """How far llvmpipe's acos, off by ``delta`` (absolute), moves ``f cos`` of the rough
    diffuse lobe: EON's multiple-scattering lobe ``c_ms (1 - E(mu_o)) (1 - E(mu_i)) /
    (pi (1 - E_avg))`` with ``E(mu) = A + r A g(mu)/pi`` and ``g`` holding ``sin acos(mu)``, so
    ``|dE| <= r A sin delta / pi``; the layers above scale it by at most 1."""
    r = float(params.get("base_diffuse_roughness", 0.0))
    if r == 0.0:
        return np.zeros(len(wi))[:, None]
    colour = np.asarray(params["base_color"], np.float64)
    weight = float(params.get("base_weight", 1.0))
    a = 1.0 / (1.0 + mxf.FUJII_1 * r)
    ci, co = wi[:, 2], wo[:, 2]
    e_i = np.asarray(mxf.fujii_dir_albedo(ci, r))
    e_o = np.asarray(mxf.fujii_dir_albedo(co, r))
    de_i = r * a * np.sqrt(1 - ci * ci) * delta / math.pi
    de_o = r * a * np.sqrt(1 - co * co) * delta / math.pi
    c_ms = np.asarray(mxf.eon_multiple_scattering_colour(colour, r))
    scale = weight * c_ms / (math.pi * (1.0 - float(mxf.fujii_avg_albedo(r))))
    return scale[None, :] * (de_o * (1 - e_i) + de_i * (1 - e_o))[:, None] * ci[:, None]


def _render(document, name, wi, wo):
    """MaterialX's value at each pair (at the first spin) and its relative spread over
    :data:`SPINS` (the largest over the channels)."""
    values = np.stack([mr.measure_in_materialx(document, name, wi, wo, spin=s)
                       for s in SPINS]).astype(np.float64)
    spread = np.abs(values - values[0]).max(axis=0) / np.maximum(np.abs(values[0]), 1e-30)
    return values[0], spread.max(axis=-1)


def _assert_parity(ours, theirs, rel, extra):
    """``|ours - theirs| <= rel |theirs| + extra + PARITY_ABS`` (``rel`` per pair)."""
    bad = np.abs(ours - theirs) > rel[:, None] * np.abs(theirs) + extra + PARITY_ABS
    assert not bad.any(), (f"{int(bad.any(axis=-1).sum())} pairs off: ours {ours[bad][:4]} "
                           f"MaterialX {theirs[bad][:4]}")


# ----------------------------------------------------------------------------- the document


def test_document_names_each_material_once_and_sets_every_input():
    exports = [cx.to_materialx("openpbr-surface-coat", {"base_color": (0.6, 0.2, 0.1),
                                                         "coat_weight": 0.5}, "red plastic"),
               cx.to_materialx("openpbr-surface", {"base_metalness": 1.0}, "2-gold")]
    root = ET.fromstring(cx.mtlx_document(exports))
    assert root.tag == "materialx" and root.get("version") == "1.39"
    mats = root.findall("surfacematerial")
    assert [m.get("name") for m in mats] == ["red_plastic", "_2_gold"]
    shader = root.find("open_pbr_surface[@name='SR_red_plastic']")
    inputs = {i.get("name"): (i.get("type"), i.get("value")) for i in shader}
    assert inputs["base_color"] == ("color3", "0.6, 0.2, 0.1")
    assert inputs["coat_weight"] == ("float", "0.5")
    assert set(inputs) == {"base_color", "base_metalness", "specular_roughness", "specular_ior",
                           "coat_weight", "coat_roughness", "coat_ior"}
    with pytest.raises(ValueError, match="distinct"):
        cx.mtlx_document([exports[0], exports[0]])


def test_only_openpbr_entries_export():
    with pytest.raises(cx.ExportError, match="openpbr-surface"):
        cx.to_materialx("ggx", {"alpha": 0.2}, "x")


def test_every_entry_exports_a_valid_document():
    """MaterialX validates each entry's export against its own libraries, and the negative
    control (a misspelt input) fails the same validation."""
    _materialx_or_skip()
    from brdf_fit import registry

    exports = [cx.to_materialx(e.name, {}, e.name) for e in registry.entries()
               if e.target == "openpbr"]
    assert len(exports) == 4
    text = cx.mtlx_document(exports)
    assert cx.validate_mtlx(text) == (True, "")
    valid, message = cx.validate_mtlx(text.replace('"coat_ior"', '"coat_iorr"'))
    assert not valid and "coat_iorr" in message


# ----------------------------------------------------------------------------- parity


def test_the_renderer_acos_is_what_the_bound_assumes():
    """llvmpipe's acos error, measured on the context the parity runs on: the rough diffuse
    case's bound takes it from here."""
    _render_or_skip()
    assert mr.glsl_error("acos", 0.0, 1.0, np.arccos) < 1e-3


@pytest.mark.parametrize("name", sorted(MATERIALS))
def test_entry_renders_as_materialx(name):
    """MaterialX's generated shader renders the exported material, at random and grazing
    pairs, as the entry evaluates it (f cos, one light of intensity 1), to float32 rounding
    (its own, :func:`~tests._helpers.float32_spread`, and the renderer's, :func:`_render`) and,
    for the rough diffuse lobe, the renderer's acos error."""
    _render_or_skip()
    entry, params = MATERIALS[name]
    wi, wo = parity_pairs(200, 20 + len(name))
    gi, go = grazing_pairs()
    wi, wo = np.concatenate([wi, gi]), np.concatenate([wo, go])
    theirs, spread = _render(_document(name, entry, params), name, wi, wo)
    model = _model(entry, params)
    ours = np.asarray(model.eval(wi, wo)) * wi[:, 2:3]
    delta = mr.glsl_error("acos", 0.0, 1.0, np.arccos)
    rel = (PARITY_REL + RENDER_SPREAD_FACTOR * spread
           + SPREAD_FACTOR * float32_spread(model, wi, wo, ROUNDINGS))
    _assert_parity(ours, theirs, rel, _acos_bound(params, wi, wo, delta))


def test_a_wrong_roughness_fails_the_parity():
    """The negative control: the same comparison with the roughness off by 0.01 fails by far
    more than the bound."""
    _render_or_skip()
    entry, params = MATERIALS["dielectric"]
    wi, wo = parity_pairs(100, 8)
    theirs = mr.measure_in_materialx(_document("d", entry, params), "d", wi, wo)
    wrong = _model(entry, {**params, "specular_roughness": 0.36})
    ours = np.asarray(wrong.eval(wi, wo)) * wi[:, 2:3]
    rel = np.abs(ours - theirs) / (np.abs(theirs) + PARITY_ABS / PARITY_REL)
    assert rel.max() > 30 * PARITY_REL


def test_an_unknown_material_is_named():
    _render_or_skip()
    doc = _document("plastic", *MATERIALS["dielectric"])
    with pytest.raises(ValueError, match="plastic"):
        mr.measure_in_materialx(doc, "nothing", np.array([[0, 0, 1.0]]), np.array([[0, 0, 1.0]]))
