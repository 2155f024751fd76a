"""The glTF 2.0 metallic-roughness model with its KHR extensions (brdf_fit.models.gltf_pbr).

The reference is an independent NumPy transcription of the specification texts (glTF 2.0
Appendix B; KHR_materials_ior, _specular, _anisotropy, _sheen, _clearcoat README files; Estevez &
Kulla 2017 for the Charlie sheen), written with plain vector algebra (normalised half vector,
explicit tangent frame, np.cross) and Appendix B's isotropic forms where the extension is off,
not with the model's JAX kernels. The sheen albedo E comes from the packaged table through an
independent NumPy cubic-Lagrange lookup (the model's documented lookup); the table itself is
checked against scipy.integrate.dblquad."""

import functools
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.integrate
from _helpers import EXTREME_UNIFORMS, dir_from_cos, random_dirs, seed_of

from brdf_fit.convert.gltf import _appendix_b, _material_arrays
from brdf_fit.core.table import load_table
from brdf_fit.models import gltf_pbr as G
from brdf_fit.tables.sheen import albedo
from brdf_fit.verify.chi2 import chi2_test

# ----------------------------------------------------------------------------- NumPy reference


def _table_np():
    import importlib.resources

    path = importlib.resources.files("brdf_fit") / "resources" / "tables" / G.SHEEN_TABLE_FILE
    with importlib.resources.as_file(path) as p:
        return load_table(p)


TABLE = _table_np()


def ref_E(mu, sr):
    """E(mu, sr) from the table values by cubic Lagrange interpolation through the 4 nearest
    endpoint nodes per axis (stencil shifted inwards at the ends), coordinates log10 clamped to
    the grid (the model's documented lookup, written again)."""
    vals = np.asarray(TABLE.values)[..., 0]
    out = np.zeros(np.broadcast(mu, sr).shape)
    coords = (np.log10(np.clip(sr, 0.01, 1.0)), np.log10(np.clip(mu, 1e-6, 1.0)))
    idx_w = []
    for ax, x in zip(TABLE.axes, np.broadcast_arrays(*coords), strict=True):
        h = (ax.hi - ax.lo) / (ax.n - 1)
        t = np.clip((x - ax.lo) / h, 0.0, ax.n - 1.0)
        s0 = np.clip(np.floor(t) - 1.0, 0.0, ax.n - 4.0)
        u = t - s0
        nodes = [0.0, 1.0, 2.0, 3.0]
        ws = []
        for j in range(4):
            wj = np.ones_like(u)
            for k in range(4):
                if k != j:
                    wj = wj * (u - nodes[k]) / (nodes[j] - nodes[k])
            ws.append(wj)
        idx_w.append((s0.astype(int), ws))
    (i0, w0), (i1, w1) = idx_w
    for a in range(4):
        for b in range(4):
            out = out + w0[a] * w1[b] * vals[i0 + a, i1 + b]
    return out


CHARLIE = {0: (25.3245, 3.32435, 0.16801, -1.27393, -4.85967),
           1: (21.5473, 3.82987, 0.19823, -1.97760, -4.32054)}


def ref_lambda_sheen(cos_t, alpha_g):
    """KHR_materials_sheen "Sheen visibility": l(x) and lambdaSheen (Estevez & Kulla 2017)."""
    one_minus_sq = (1.0 - alpha_g) ** 2

    def lerp(k):
        return CHARLIE[1][k] * (1 - one_minus_sq) + CHARLIE[0][k] * one_minus_sq

    a, b, c, d, e = (lerp(k) for k in range(5))

    def ell(x):
        return a / (1.0 + b * np.power(x, c)) + d * x + e

    return np.where(np.abs(cos_t) < 0.5, np.exp(ell(np.abs(cos_t))),
                    np.exp(2.0 * ell(0.5) - ell(1.0 - np.abs(cos_t))))


def ref_sheen_lobe(L, V, sheen_roughness):
    """D_Charlie V_Charlie of KHR_materials_sheen (alphaG = sheenRoughness^2, floored at 1e-4)."""
    N = np.array([0.0, 0.0, 1.0])
    H = (L + V) / np.linalg.norm(L + V, axis=-1, keepdims=True)
    alpha_g = max(sheen_roughness**2, 1e-4)
    sin2h = np.sum(np.cross(N, H) ** 2, axis=-1)  # |N x H|^2 = 1 - (N.H)^2
    inv_r = 1.0 / alpha_g
    D = (2.0 + inv_r) * np.power(sin2h, 0.5 * inv_r) / (2.0 * np.pi)
    nl, nv = L @ N, V @ N
    vis = 1.0 / ((1.0 + ref_lambda_sheen(nv, alpha_g) + ref_lambda_sheen(nl, alpha_g))
                 * (4.0 * nv * nl))
    return D * vis


def ref_gltf(p, L, V):
    """The material BRDF of the specification texts at (N, 3) float64 directions, (N, 3) RGB."""
    p = {**{k: np.asarray(v, float) for k, v in G.GLTF_DEFAULTS.items()},
         **{k: np.asarray(v, float) for k, v in p.items()}}
    rgb = {k: np.broadcast_to(p[k], 3) for k in ("base_color", "specular_color", "sheen_color")}
    N = np.array([0.0, 0.0, 1.0])
    Hu = L + V
    H = Hu / np.linalg.norm(Hu, axis=-1, keepdims=True)
    # |V.H| as |L + V|/2 (equal for unit vectors; V.H itself takes the rounding of H, 5e-10
    # absolute at the grazing pair of opposite azimuths where |L + V| = 2e-7)
    NL, NV, NH, VH = L @ N, V @ N, H @ N, np.minimum(0.5 * np.linalg.norm(Hu, axis=-1), 1.0)
    alpha = max(float(p["roughness"]) ** 2, 1e-4)
    s = float(p["anisotropy_strength"])
    # (N.H)^2 (a^2 - 1) + 1 of Appendix B.3.2 as |N x H|^2 + a^2 (N.H)^2: the same number without
    # the cancellation of 1 - (N.H)^2 (1e-8 relative at alpha = 1e-4 next to the mirror pair)
    sin2h = np.sum(np.cross(N, H) ** 2, axis=-1)
    if s == 0:  # Appendix B.3.2, isotropic
        a2 = alpha * alpha
        D = a2 / (np.pi * (sin2h + a2 * NH * NH) ** 2)
        Vis = 1.0 / (2.0 * (NV * np.sqrt(a2 + (1 - a2) * NL**2)
                            + NL * np.sqrt(a2 + (1 - a2) * NV**2)))
    else:  # KHR_materials_anisotropy: D and V_GGX_anisotropic
        at, ab = alpha * (1 - s * s) + 1.0 * s * s, alpha
        rot = float(p["anisotropy_rotation"])
        T = np.array([math.cos(rot), math.sin(rot), 0.0])  # TBN * (cos, sin, 0)
        B = np.cross(N, T)
        D = 1.0 / (np.pi * at * ab * ((H @ T / at) ** 2 + (H @ B / ab) ** 2 + NH**2) ** 2)
        ggx_v = NL * np.linalg.norm(np.stack([at * (V @ T), ab * (V @ B), NV], -1), axis=-1)
        ggx_l = NV * np.linalg.norm(np.stack([at * (L @ T), ab * (L @ B), NL], -1), axis=-1)
        Vis = 0.5 / (ggx_v + ggx_l)
    specular_brdf = (Vis * D)[:, None]
    fw = ((1.0 - VH) ** 5)[:, None]
    base = rgb["base_color"]
    diffuse_brdf = base / np.pi
    ior = float(p["ior"])
    sf = float(p["specular_factor"])
    f0 = np.minimum(((ior - 1) / (ior + 1)) ** 2 * rgb["specular_color"], 1.0) * sf
    dielectric_fresnel = f0 + (sf - f0) * fw  # mix(f0, f90, fresnel_w)
    dielectric = (dielectric_fresnel * specular_brdf
                  + (1.0 - dielectric_fresnel.max(-1, keepdims=True)) * diffuse_brdf)
    metal = specular_brdf * (base + (1 - base) * fw)
    m = float(p["metallic"])
    material = dielectric * (1 - m) + metal * m
    # KHR_materials_sheen: f_sheen + material * sheenAlbedoScaling (scaling clamped at 0)
    sc = rgb["sheen_color"]
    sr = float(p["sheen_roughness"])
    f_sheen = sc * ref_sheen_lobe(L, V, sr)[:, None]
    scaling = np.minimum(1.0 - sc.max() * ref_E(NV, sr), 1.0 - sc.max() * ref_E(NL, sr))
    f = f_sheen + material * np.maximum(scaling, 0.0)[:, None]
    # KHR_materials_clearcoat: mix(f, clearcoat_brdf, clearcoat * clearcoat_fresnel)
    ac = max(float(p["clearcoat_roughness"]) ** 2, 1e-4)
    ac2 = ac * ac
    Dc = ac2 / (np.pi * (sin2h + ac2 * NH * NH) ** 2)
    Gc = 2 * NL * NV / (NV * np.sqrt(ac2 + (1 - ac2) * NL**2) + NL * np.sqrt(ac2 + (1 - ac2)
                                                                          * NV**2))
    cc_brdf = (Dc * Gc / (4 * NV * NL))[:, None]
    cc_fresnel = (0.04 + (1 - 0.04) * (1 - np.abs(NV)) ** 5)[:, None]
    w = float(p["clearcoat"]) * cc_fresnel
    return f * (1 - w) + cc_brdf * w


# ----------------------------------------------------------------------------- fixtures
# Compilation dominates this file's time, so every model here has one pytree structure (all
# twelve parameters as arrays, colours RGB; the registry builder and from_gltf_material build
# the same) and the compiled functions below are shared by the tests: VPG (values, pdf and
# gradients, float64 and float32, N_PAIRS pairs), the sampler and the pdf at the chi-square's
# chunk (CHUNK).

#: direction pairs of every evaluation (random + grazing; the hard-case grid padded with random)
N_PAIRS = 150

#: XLA's LLVM backend at optimisation level 0: half the compilation time of these programs
#: (measured 18.5 s -> 8.6 s for VPG on a loaded 2-core machine), 1-3x their run time, which is
#: small here; the arithmetic (IEEE, no fast-math) is the same
FAST_COMPILE = {"xla_backend_optimization_level": 0}


@functools.partial(jax.jit, compiler_options=FAST_COMPILE)
def VPG(p, wi, wo, weights):
    """``(eval, pdf, value, grads)``: ``value = sum(eval weights) + 1e-2 sum(pdf)`` and its
    gradient in ``(p, wi, wo)``."""

    def total(q, a, b):
        m = G.GltfPBR(**q)
        f, pdf = m.eval(a, b), m.pdf(a, b)
        return jnp.sum(f * weights) + 1e-2 * jnp.sum(pdf), (f, pdf)

    (value, (f, pdf)), grads = jax.value_and_grad(total, argnums=(0, 1, 2), has_aux=True)(
        p, wi, wo)
    return f, pdf, value, grads


@functools.partial(jax.jit, compiler_options=FAST_COMPILE)
def SAMPLE(m, wo, uc, u):
    """``(wi, pdf, weight)`` of ``m.sample``; every call has ``CHUNK`` rows of everything."""
    s = m.sample(wo, uc, u)
    return s.wi, s.pdf, s.weight


def EVAL(m, wi, wo):
    """``m.eval(wi, wo)`` through VPG (one compiled program for values and gradients; every
    direction set of this file has N_PAIRS pairs)."""
    p = {k: getattr(m, k) for k in G.GLTF_DEFAULTS}
    return VPG(p, wi, wo, jnp.ones(wi.shape, wi.dtype))[0]


PDF = jax.jit(lambda m, wi, wo: m.pdf(wi, jnp.broadcast_to(wo, wi.shape)),
              compiler_options=FAST_COMPILE)
#: brdf_fit.convert.gltf.appendix_b_eval's kernel, compiled once
APPENDIX_B = jax.jit(_appendix_b, compiler_options=FAST_COMPILE)
#: samples per call of SAMPLE and PDF (the chi-square's chunk), and per chi-square test
CHUNK = 16384
N_CHI2 = 65536


def full_params(p, dtype=jnp.float64):
    """Every GltfPBR parameter as an array (colours RGB): ``p`` over the spec's defaults."""
    out = {}
    for k, v in G.GLTF_DEFAULTS.items():
        x = np.asarray(p.get(k, v), float)
        out[k] = jnp.asarray(np.broadcast_to(x, (3,)) if k in ("base_color", "specular_color",
                                                                "sheen_color") else x, dtype)
    return out


def model_of(p, dtype=jnp.float64):
    return G.GltfPBR(**full_params(p, dtype))


def grazing_pairs():
    """Grazing, opposite-azimuth, same-azimuth, wi = wo and mirror pairs."""
    wi, wo = [], []
    for ci in (1e-7, 1e-4, 1e-2, 0.3, 1.0):
        for co in (1e-7, 1e-4, 1e-2, 0.7):
            for pi_, po in ((0.3, 2.1), (1.0, 1.0), (0.0, math.pi), (2.0, 2.0 + math.pi)):
                wi.append(dir_from_cos(ci, pi_))
                wo.append(dir_from_cos(co, po))
    for c in (1e-4, 0.2, 0.9):
        w = dir_from_cos(c, 0.7)
        wi += [w, w * np.array([-1.0, -1.0, 1.0])]
        wo += [w, w]
    return np.asarray(wi), np.asarray(wo)


def pairs():
    rng = np.random.default_rng(seed_of("gltf-pairs"))
    gi, go = grazing_pairs()
    return (np.concatenate([random_dirs(rng, 64), gi]),
            np.concatenate([random_dirs(rng, 64), go]))


WI, WO = pairs()
assert WI.shape[0] == N_PAIRS
WI_J, WO_J = jnp.asarray(WI), jnp.asarray(WO)
RGB = (0.8, 0.35, 0.1)

#: one parameter set per extension (and combinations); the base is a coloured dielectric
CASES = {
    "appendix-b-dielectric": {"base_color": RGB, "metallic": 0.0, "roughness": 0.5},
    "appendix-b-metal": {"base_color": RGB, "metallic": 1.0, "roughness": 0.3},
    "appendix-b-mixed-smooth": {"base_color": RGB, "metallic": 0.4, "roughness": 0.1},
    "appendix-b-roughness-0": {"base_color": RGB, "metallic": 0.2, "roughness": 0.0},
    "ior": {"base_color": RGB, "metallic": 0.0, "roughness": 0.4, "ior": 2.4},
    "ior-0": {"base_color": RGB, "metallic": 0.3, "roughness": 0.4, "ior": 0.0},
    "specular": {"base_color": RGB, "metallic": 0.2, "roughness": 0.45, "ior": 1.33,
                 "specular_factor": 0.7, "specular_color": (1.5, 30.0, 0.2)},
    "anisotropy": {"base_color": RGB, "metallic": 0.5, "roughness": 0.3,
                   "anisotropy_strength": 0.7, "anisotropy_rotation": 0.6},
    "anisotropy-full": {"base_color": RGB, "metallic": 0.0, "roughness": 0.05,
                        "anisotropy_strength": 1.0, "anisotropy_rotation": -2.5},
    "sheen": {"base_color": RGB, "metallic": 0.0, "roughness": 0.6,
              "sheen_color": (0.9, 0.5, 0.2), "sheen_roughness": 0.4},
    "sheen-smooth": {"base_color": RGB, "metallic": 0.0, "roughness": 0.6,
                     "sheen_color": (0.3, 0.6, 0.1), "sheen_roughness": 0.05},
    "sheen-roughness-0": {"base_color": RGB, "metallic": 0.1, "roughness": 0.6,
                          "sheen_color": (0.2, 0.2, 0.25), "sheen_roughness": 0.0},
    "clearcoat": {"base_color": RGB, "metallic": 0.3, "roughness": 0.6, "clearcoat": 0.8,
                  "clearcoat_roughness": 0.25},
    "clearcoat-roughness-0": {"base_color": RGB, "metallic": 0.0, "roughness": 0.6,
                              "clearcoat": 1.0, "clearcoat_roughness": 0.0},
    "everything": {"base_color": RGB, "metallic": 0.25, "roughness": 0.35, "ior": 1.7,
                   "specular_factor": 0.8, "specular_color": (0.9, 1.2, 0.6),
                   "anisotropy_strength": 0.5, "anisotropy_rotation": 1.1,
                   "sheen_color": (0.4, 0.3, 0.6), "sheen_roughness": 0.3,
                   "clearcoat": 0.6, "clearcoat_roughness": 0.15},
}


# ----------------------------------------------------------------------------- values


@pytest.mark.parametrize("case", list(CASES))
def test_matches_numpy_reference_of_the_specification(case):
    """Random and grazing pairs, every extension: 1e-10 relative in float64 (the RGB triple's
    largest value is the scale of each channel, so a channel that cancels to ~1e-17 does not
    demand digits its inputs do not have)."""
    p = CASES[case]
    got = np.asarray(EVAL(model_of(p), WI_J, WO_J))
    want = ref_gltf(p, WI, WO)
    scale = np.maximum(np.abs(want).max(-1, keepdims=True), 1e-300)
    err = np.abs(got - want) / scale
    assert np.all(np.isfinite(got)) and np.all(got >= 0)
    assert err.max() <= 1e-10, (case, err.max(), np.unravel_index(err.argmax(), err.shape))


#: unit roundoff of float64
U64 = 2.0**-53
#: relative rounding of the exporter's N.H, in units of U64, for ANY order and contraction XLA may
#: compile (SSE, AVX2, AVX-512, with or without FMA): L + V (1), the squared norm of three
#: non-negative terms (gamma_3 = 3, half of it through the square root: 1.5), its reciprocal
#: square root (at most 2.5: a square root and a division, or an approximation refined to that),
#: the product H_z = h_z / |h| (1); then N.H^2 (alpha^2 - 1) adds one rounding of its own. 7 in all.
NH_ROUNDINGS = 7.0


def _appendix_b_rounding_bound(alpha, wi, wo):
    """Per pair, the relative error the exporter's Appendix B evaluator may carry by rounding alone.

    It forms D's denominator d = (N.H)^2 (alpha^2 - 1) + 1 as written, which cancels next to the
    mirror pair (d -> alpha^2): a relative error e of N.H moves D by kappa e, with
    kappa = |d ln D / d ln N.H| = 4 (N.H)^2 (1 - alpha^2) / d, evaluated here without cancellation
    (1 - (N.H)^2 = (h_x^2 + h_y^2) / |h|^2). The bound is kappa NH_ROUNDINGS U64 (at the mirror
    pair of alpha = 1e-4: 3.1e-7; measured there 5.5e-8 to 8.0e-8 with AVX-512 code and 1.0e-8 with
    AVX2 on one AMD EPYC; the model itself is within 1.2e-16 of a 50-digit evaluation of the same
    formula at those pairs); it also takes |V.H| as V.H with the rounding of H, ~1e-16/|L + V|
    (the model: |L + V|/2), and never less than 1e-12."""
    h = wi + wo
    hh = np.sum(h * h, axis=1)
    nh2 = h[:, 2] ** 2 / hh
    a2 = alpha**2
    d = a2 * nh2 + (h[:, 0] ** 2 + h[:, 1] ** 2) / hh  # (N.H)^2 (a^2 - 1) + 1, no cancellation
    kappa = 4.0 * nh2 * (1.0 - a2) / d
    return np.maximum(np.maximum(1e-12, kappa * NH_ROUNDINGS * U64), 1e-15 / np.sqrt(hh))


def test_matches_the_exporters_appendix_b_evaluator():
    """brdf_fit.convert.gltf.appendix_b_eval (base + KHR_materials_ior + _specular) on random
    materials, through the glTF material dict of to_gltf_material."""
    rng = np.random.default_rng(seed_of("appendix-b-agreement"))
    for k in range(6):
        p = {"base_color": tuple(rng.uniform(0, 1, 3)), "metallic": float(rng.uniform()),
             "roughness": float(rng.uniform(0.0, 1.0) if k else 0.0),
             "ior": float(rng.uniform(1.0, 2.5)), "specular_factor": float(rng.uniform()),
             "specular_color": tuple(rng.uniform(0, 3, 3))}
        mat, _ = G.to_gltf_material(p, f"m{k}")
        want = np.asarray(APPENDIX_B(*_material_arrays(mat), WI_J, WO_J))
        got = np.asarray(EVAL(model_of(p), WI_J, WO_J))
        scale = np.maximum(np.abs(want).max(-1, keepdims=True), 1e-300)
        tol = _appendix_b_rounding_bound(max(p["roughness"] ** 2, 1e-4), WI, WO)
        assert np.all(np.abs(got - want) / scale <= tol[:, None]), k


def test_defaults_are_the_specifications():
    m = G.GltfPBR()
    for k, v in G.GLTF_DEFAULTS.items():
        assert np.all(np.asarray(getattr(m, k)) == np.asarray(v)), k
    # every extension off: Appendix B's rough white metal
    got = np.asarray(EVAL(model_of({}), WI_J, WO_J))
    want = ref_gltf({"base_color": 1.0, "metallic": 1.0, "roughness": 1.0}, WI, WO)
    assert np.max(np.abs(got - want) / np.maximum(want, 1e-300)) <= 1e-12


def test_reciprocity_and_the_clearcoats_view_fresnel():
    """Every layer but the clearcoat is symmetric in (wi, wo); the clearcoat's F_c(N.V) is not
    (KHR_materials_clearcoat, declared as the entry's expected failure)."""
    sym = model_of({**CASES["everything"], "clearcoat": 0.0})
    a, b = EVAL(sym, WI_J, WO_J), EVAL(sym, WO_J, WI_J)
    assert np.allclose(a, b, rtol=1e-12, atol=0)
    coated = model_of(CASES["everything"])
    c, d = np.asarray(EVAL(coated, WI_J, WO_J)), np.asarray(EVAL(coated, WO_J, WI_J))
    assert np.max(np.abs(c - d) / np.maximum(np.abs(c), 1e-300)) > 1e-3
    entry = {e.name: e for e in G.registry_entries()}["gltf-pbr-clearcoat"]
    assert "reciprocity" in entry.expected_failures


# ----------------------------------------------------------------------------- gradients and
# hard cases (one compiled VPG per dtype at the 87 pairs of the hard-case grid)

FD_PARAMS = {"base_color": (0.7, 0.4, 0.2), "metallic": 0.3, "roughness": 0.45, "ior": 1.6,
             "specular_factor": 0.8, "specular_color": (0.9, 1.3, 0.5),
             "anisotropy_strength": 0.55, "anisotropy_rotation": 0.4,
             "sheen_color": (0.5, 0.3, 0.7), "sheen_roughness": 0.35, "clearcoat": 0.6,
             "clearcoat_roughness": 0.3}


def _hard_directions(dtype):
    """brdf_fit.verify.checks' hard-case pairs (87), then random pairs up to N_PAIRS."""
    from brdf_fit.verify.checks import hard_case_directions

    wi, wo = hard_case_directions()
    n = N_PAIRS - wi.shape[0]
    wi, wo = np.concatenate([wi, WI[:n]]), np.concatenate([wo, WO[:n]])
    return jnp.asarray(wi, dtype), jnp.asarray(wo, dtype)


def test_gradients_match_central_differences():
    """d/d(every parameter entry) of sum(f * weights) + 1e-2 sum(pdf) against central
    differences in float64 (step 1e-6), at random pairs (cosines >= 0.05)."""
    n = _hard_directions(jnp.float64)[0].shape[0]
    rng = np.random.default_rng(seed_of("gltf-fd"))
    wi, wo = jnp.asarray(random_dirs(rng, n, 0.05)), jnp.asarray(random_dirs(rng, n, 0.05))
    weights = jnp.asarray(rng.uniform(0.5, 1.5, (n, 3)))
    p0 = full_params(FD_PARAMS)
    grad = VPG(p0, wi, wo, weights)[3][0]
    h = 1e-6
    for k, v in p0.items():
        v = np.asarray(v)
        for idx in np.ndindex(v.shape):
            up, dn = v.copy(), v.copy()
            up[idx] += h
            dn[idx] -= h
            fu = VPG({**p0, k: jnp.asarray(up)}, wi, wo, weights)[2]
            fd = VPG({**p0, k: jnp.asarray(dn)}, wi, wo, weights)[2]
            num = float(fu - fd) / (2 * h)
            g = float(np.asarray(grad[k])[idx])
            assert g == pytest.approx(num, rel=1e-6, abs=1e-7), (k, idx, g, num)


HARD = {
    "roughness-0": {"roughness": 0.0, "metallic": 0.0, "base_color": RGB},
    "all-rough": {"roughness": 1.0, "sheen_color": 1.0, "sheen_roughness": 1.0,
                  "clearcoat": 1.0, "clearcoat_roughness": 1.0, "anisotropy_strength": 1.0},
    "all-smooth": {"roughness": 0.0, "metallic": 0.5, "sheen_color": 1.0,
                   "sheen_roughness": 0.0, "clearcoat": 1.0, "clearcoat_roughness": 0.0,
                   "anisotropy_strength": 1.0, "anisotropy_rotation": 1000.0},
    "ior-0-black-metal": {"ior": 0.0, "metallic": 1.0, "base_color": 0.0, "roughness": 0.01},
    "ior-1-no-specular": {"ior": 1.0, "specular_factor": 0.0, "metallic": 0.0,
                          "sheen_color": 0.3, "sheen_roughness": 0.009},
    "everything": CASES["everything"],
}


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64], ids=["f32", "f64"])
def test_values_gradients_and_samples_finite_on_hard_cases(dtype):
    """brdf_fit.verify.checks' hard-case directions (grazing 1e-7, opposite azimuths, wi = wo,
    mirror pairs, both on the horizon with wi = -wo) with extreme parameters: values and pdfs
    finite and >= 0, gradients in every parameter and both directions finite; in float64 also
    samples at extreme uniforms finite, failed ones with weight 0 (float32 sampling: the
    registry's contract tests, tests/models/test_hard_cases.py). float32 agrees with float64 to
    float32 rounding on the pairs with both cosines >= 0.01."""
    wi, wo = _hard_directions(dtype)
    ones = jnp.ones(wi.shape[:1] + (3,), dtype)
    for name, p in HARD.items():
        f, pdf, value, grads = VPG(full_params(p, dtype), wi, wo, ones)
        for what, x in (("eval", f), ("pdf", pdf)):
            x = np.asarray(x)
            assert x.dtype == np.dtype(dtype) and np.all(np.isfinite(x)) and np.all(x >= 0), \
                (name, what)
        for path, leaf in jax.tree_util.tree_leaves_with_path(grads):
            assert np.all(np.isfinite(np.asarray(leaf))), (name, path)
        if dtype == jnp.float64:
            sampling_finite(model_of(p, dtype), dtype)
    if dtype == jnp.float32:
        w64, o64 = _hard_directions(jnp.float64)
        f32 = np.asarray(VPG(full_params(CASES["everything"], dtype), wi, wo, ones)[0])
        f64 = np.asarray(VPG(full_params(CASES["everything"]), w64, o64,
                             jnp.ones(f32.shape))[0])
        keep = (np.minimum(w64[:, 2], o64[:, 2]) >= 0.01) & (np.linalg.norm(w64 + o64, axis=1)
                                                              > 0.1)
        rel = np.abs(f32 - f64)[keep] / np.abs(f64[keep]).max(-1, keepdims=True)
        assert keep.sum() > 20 and rel.max() < 1e-4, rel.max()


# ----------------------------------------------------------------------------- sampling


def chunk_of(wo, dtype=jnp.float64):
    """A view (3,) repeated to CHUNK rows."""
    return jnp.asarray(np.broadcast_to(np.asarray(wo, float), (CHUNK, 3)), dtype)


def sampling_finite(m, dtype):
    """SAMPLE at views of cosine 1e-7, 0.5, 1 (and one below the horizon) with the 4 x 4 grid of
    extreme uniforms (both ends of [0, 1) and next to them) and 16 lobe uniforms from 0 to
    1 - 1e-7, in one call (padded to CHUNK): wi, pdf, weight finite, weight 0 where pdf is 0,
    pdf 0 below the horizon."""
    us = np.asarray(EXTREME_UNIFORMS)
    u = np.tile(np.stack(np.meshgrid(us, us), -1).reshape(-1, 2), (16, 1))
    uc = np.repeat(np.linspace(0.0, 1 - 1e-7, 16), 16)
    views = [dir_from_cos(c, 0.4) for c in (1e-7, 0.5, 1.0)] + [np.array([0.6, 0.0, -0.8])]
    wo = np.concatenate([np.broadcast_to(v, (256, 3)) for v in views])
    pad = CHUNK - wo.shape[0]
    wi, pdf, wt = SAMPLE(m, jnp.asarray(np.concatenate([wo, np.tile([0.0, 0.0, 1.0], (pad, 1))]),
                                        dtype),
                         jnp.asarray(np.concatenate([np.tile(uc, 4), np.full(pad, 0.5)]), dtype),
                         jnp.asarray(np.concatenate([np.tile(u, (4, 1)), np.full((pad, 2), 0.5)]),
                                     dtype))
    for x in (wi, pdf, wt):
        assert np.all(np.isfinite(np.asarray(x)))
    pdf, wt = np.asarray(pdf), np.asarray(wt)
    assert np.all(wt[pdf == 0] == 0) and np.all(pdf[768:1024] == 0)


CHI2_MODEL = {"base_color": RGB, "metallic": 0.3, "roughness": 0.4, "anisotropy_strength": 0.6,
              "anisotropy_rotation": 0.8, "sheen_color": (0.6, 0.5, 0.4),
              "sheen_roughness": 0.3, "clearcoat": 0.7, "clearcoat_roughness": 0.35}


@pytest.mark.parametrize("cos_o", [0.8, 0.15])
def test_sampler_matches_pdf_chi_square(cos_o):
    """The four-lobe mixture (cosine, uniform, anisotropic GGX visible normals rotated, clearcoat
    GGX visible normals) against its pdf (brdf_fit.verify.chi2), two views, Sidak over 2."""
    m = model_of(CHI2_MODEL)
    wo = jnp.asarray(dir_from_cos(cos_o, 0.4))
    wos = chunk_of(wo)
    r = chi2_test(lambda uc, u: SAMPLE(m, wos, uc, u)[:2], lambda wi: PDF(m, wi, wo),
                  n_samples=N_CHI2, seed=seed_of("gltf-chi2", cos_o), test_count=2,
                  cell_nodes=8, chunk_size=CHUNK, lobe_uniform=True)
    assert r.passed, f"{r}\n{r.worst_cells(6)}"
    assert r.pdf_mismatch_fraction == 0.0
    print(f"cos_o {cos_o}: p = {r.p_value:.3g} (statistic {r.statistic:.1f}, dof {r.dof})")


def test_negative_control_chi_square_rejects_an_unrotated_pdf():
    """A pdf that forgets the anisotropy rotation (0.8 rad) of the lobe the sampler draws must
    fail at the same sample count: the test can see a mistake of that kind."""
    m = model_of(CHI2_MODEL)
    unrotated = model_of({**CHI2_MODEL, "anisotropy_rotation": 0.0})
    wo = jnp.asarray(dir_from_cos(0.8, 0.4))
    wos = chunk_of(wo)
    r = chi2_test(lambda uc, u: SAMPLE(m, wos, uc, u)[:2], lambda wi: PDF(unrotated, wi, wo),
                  n_samples=N_CHI2, seed=seed_of("gltf-chi2-negative"), test_count=2,
                  cell_nodes=8, chunk_size=CHUNK, lobe_uniform=True, check_pdf=False)
    assert not r.passed
    print(f"unrotated pdf: p = {r.p_value:.3g}")


def test_sample_weights_and_failed_samples():
    m = model_of(CHI2_MODEL)
    rng = np.random.default_rng(seed_of("gltf-weights"))
    wo = jnp.asarray(dir_from_cos(0.05, 1.0))
    wi, pdf, wt = SAMPLE(m, chunk_of(wo), jnp.asarray(rng.uniform(size=CHUNK)),
                         jnp.asarray(rng.uniform(size=(CHUNK, 2))))
    pdf, wt = np.asarray(pdf), np.asarray(wt)
    ok = pdf > 0
    assert 0 < np.sum(~ok) < CHUNK // 4  # grazing view: reflections below the horizon fail
    assert np.all(wt[~ok] == 0)
    assert np.allclose(pdf[ok], np.asarray(PDF(m, wi, wo))[ok], rtol=1e-12)
    wob = jnp.broadcast_to(wo, wi.shape)
    f = np.asarray(EVAL(m, wi[:N_PAIRS], wob[:N_PAIRS])) * np.asarray(wi[:N_PAIRS, 2:3])
    k = ok[:N_PAIRS]
    assert np.allclose(wt[:N_PAIRS][k], f[k] / pdf[:N_PAIRS][k, None], rtol=1e-12)


# ----------------------------------------------------------------------------- sheen table


def _sheen_cos_scalar(phi, mu_i, mu_o, sr):
    """2 f_sheen cos(theta_i) in angles with the math module (for scipy's adaptive rule)."""
    r = max(sr * sr, 1e-4)
    si, so = math.sqrt(max(0.0, 1 - mu_i * mu_i)), math.sqrt(1 - mu_o * mu_o)
    hx, hy, hz = si * math.cos(phi) + so, si * math.sin(phi), mu_i + mu_o
    s2 = (hx * hx + hy * hy) / (hx * hx + hy * hy + hz * hz)
    D = (2 + 1 / r) * s2 ** (0.5 / r) / (2 * math.pi)
    t = (1.0 - r) ** 2
    a, b, c, d, e = (CHARLIE[1][k] * (1 - t) + CHARLIE[0][k] * t for k in range(5))

    def lam(mu):
        def ell(x):
            return a / (1.0 + b * x**c) + d * x + e

        return math.exp(ell(mu)) if mu < 0.5 else math.exp(2.0 * ell(0.5) - ell(1.0 - mu))

    return 2.0 * D / ((1.0 + lam(mu_o) + lam(mu_i)) * 4.0 * mu_o)


def _dblquad_E(mu_o, sr):
    """E by scipy.integrate.dblquad (mu_i outer in panels, phi in [0, pi] inner, x 2)."""
    total = 0.0
    breaks = (0.0, 0.01, 0.1, 0.4, 1.0)
    for a, b in zip(breaks[:-1], breaks[1:], strict=True):
        v, _ = scipy.integrate.dblquad(lambda phi, m: _sheen_cos_scalar(phi, m, mu_o, sr), a, b,
                                       0.0, math.pi, epsabs=1e-10, epsrel=1e-9)
        total += v
    return total


SHEEN_E = jax.jit(G.sheen_albedo, compiler_options=FAST_COMPILE)


def test_sheen_table_against_scipy_and_its_stated_accuracy():
    acc = TABLE.meta["accuracy"]
    assert acc["max_abs"] <= G.SHEEN_TABLE_ERROR
    assert acc["max_abs"] == pytest.approx(acc["interpolation"] + acc["quadrature"])
    # (0.5, 0.5): next to Lambda's C1 join at mu = 0.5, where the cubic lookup errs most
    for mu, sr in ((0.5, 0.5), (0.12, 0.3), (0.33, 0.13)):
        want = _dblquad_E(mu, sr)
        got = float(SHEEN_E(jnp.asarray(np.float64(mu)), jnp.asarray(np.float64(sr))))
        assert abs(got - want) <= G.SHEEN_TABLE_ERROR, (mu, sr, got, want)
        print(f"E({mu}, {sr}): table {got:.8f}, dblquad {want:.8f}, |diff| {abs(got - want):.2g}")
    # the shipped table equals a regeneration (brdf_fit.tables.sheen) at spot nodes
    ax_r, ax_mu = TABLE.axes
    ii, jj = np.array([0, 17, 64, 100, 128, 128]), np.array([0, 96, 150, 180, 191, 192])
    regen = albedo(10.0 ** ax_mu.nodes()[jj], 10.0 ** ax_r.nodes()[ii])
    np.testing.assert_allclose(np.asarray(TABLE.values)[ii, jj, 0], regen, rtol=1e-12, atol=0)
    # at the nodes the lookup returns the stored values; below the clamps it is flat
    i, j = 40, 150
    node = SHEEN_E(jnp.asarray(10.0 ** ax_mu.nodes()[j]), jnp.asarray(10.0 ** ax_r.nodes()[i]))
    assert float(node) == pytest.approx(float(TABLE.values[i, j, 0]), rel=1e-12)
    g = jax.jit(jax.grad(G.sheen_albedo, argnums=(0, 1)))(jnp.asarray(3e-7), jnp.asarray(0.005))
    assert float(g[0]) == 0.0 and float(g[1]) == 0.0


# ----------------------------------------------------------------------------- export


ROUND_TRIP = {
    "spec-defaults": {},
    "core-only": {"base_color": RGB, "metallic": 0.0, "roughness": 0.25},
    "everything": CASES["everything"],
    "metal-drops-dielectric-extensions": {"base_color": RGB, "metallic": 1.0, "ior": 2.0,
                                          "specular_color": (2.0, 1.0, 1.0)},
    "inactive-layers": {"base_color": 0.5, "metallic": 0.0, "sheen_roughness": 0.7,
                        "clearcoat_roughness": 0.4, "anisotropy_rotation": 0.9},
}
EXPECTED_EXTENSIONS = {
    "spec-defaults": [], "core-only": [],
    "everything": ["KHR_materials_anisotropy", "KHR_materials_clearcoat", "KHR_materials_ior",
                   "KHR_materials_sheen", "KHR_materials_specular"],
    "metal-drops-dielectric-extensions": [], "inactive-layers": [],
}


@pytest.mark.parametrize("case", list(ROUND_TRIP))
def test_gltf_material_round_trip_is_lossless(case):
    p = ROUND_TRIP[case]
    mat, used = G.to_gltf_material(p, case)
    assert used == EXPECTED_EXTENSIONS[case]
    assert sorted(mat.get("extensions", {})) == used
    back = json.loads(json.dumps(mat))  # plain JSON
    assert back["name"] == case
    a = EVAL(G.from_gltf_material(back), WI_J, WO_J)
    b = EVAL(model_of(p), WI_J, WO_J)
    assert np.array_equal(np.asarray(a), np.asarray(b))


def test_export_writes_only_non_default_values_and_refuses_invalid_ones():
    mat, _ = G.to_gltf_material({"metallic": 0.0, "specular_factor": 0.5,
                                 "anisotropy_strength": 0.3, "sheen_color": (0.1, 0, 0),
                                 "clearcoat": 0.2}, "x")
    ext = mat["extensions"]
    assert ext["KHR_materials_specular"] == {"specularFactor": 0.5}
    assert ext["KHR_materials_anisotropy"] == {"anisotropyStrength": 0.3}
    assert ext["KHR_materials_sheen"] == {"sheenColorFactor": [0.1, 0.0, 0.0]}
    assert ext["KHR_materials_clearcoat"] == {"clearcoatFactor": 0.2}
    assert mat["pbrMetallicRoughness"]["baseColorFactor"] == [1.0, 1.0, 1.0, 1.0]
    for bad in ({"ior": 0.5}, {"roughness": 1.5}, {"base_color": (1, 2)}, {"alpha": 0.1},
                {"specular_color": -1.0}):
        with pytest.raises(ValueError):
            G.to_gltf_material(bad, "bad")
    with pytest.raises(ValueError, match="ior"):
        G.GltfPBR(ior=0.7)


# ----------------------------------------------------------------------------- registry


def test_registry_entries_build_one_structure_and_export():
    entries = {e.name: e for e in G.registry_entries()}
    assert list(entries) == ["gltf-pbr", "gltf-pbr-specular", "gltf-pbr-anisotropy",
                             "gltf-pbr-sheen", "gltf-pbr-clearcoat"]
    for e in entries.values():
        assert {"native", "gltf"} <= set(e.tags)
        assert e.param_names[:3] == ("base_color", "metallic", "roughness")
        m = e.build()
        assert jax.tree_util.tree_structure(m) == jax.tree_util.tree_structure(model_of({}))
        mat, _ = G.to_gltf_material({k: np.asarray(v) for k, v in e.defaults().items()}, e.name)
        f = EVAL(m, WI_J, WO_J)
        assert np.array_equal(f, EVAL(G.from_gltf_material(mat), WI_J, WO_J)), e.name
        assert np.all(np.asarray(f) >= 0)
    assert "anisotropic" in entries["gltf-pbr-anisotropy"].tags
    assert entries["gltf-pbr-anisotropy"].build().is_anisotropic()
    assert not entries["gltf-pbr"].build().is_anisotropic()
    assert "ior" not in entries["gltf-pbr-specular"].param_names
