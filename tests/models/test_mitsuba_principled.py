"""MitsubaPrincipled against the installed Mitsuba 3 ``principled`` plugin (parity of eval and
pdf, defaults, reciprocity as measured, Mitsuba's departures from Burley), and on its own
(finite-difference gradients of eval and pdf in every parameter, finite values and gradients at
the hard cases in float32 and float64, chi-square of the sampler against the pdf at two views,
recovery of the parameters from noise-free Mitsuba data).

Parity tolerance. Mitsuba evaluates in float32 (``scalar_rgb``); the model is evaluated in
float64 on the same float32-rounded directions, so the difference is Mitsuba's own rounding.
Each lane is allowed ``PARITY_ULPS`` float32 epsilons, plus, where the clearcoat contributes,
Mitsuba's float32 conditioning of the GTR1 denominator ``1 + (a^2 - 1)(n.h)^2`` (a cancellation
near the peak: relative error ``~eps (n.h)^2 / (1 + (a^2 - 1)(n.h)^2)``, up to ``eps / a^2``;
the model writes it as ``h.x^2 + h.y^2 + a^2 h.z^2``) times the clearcoat's share.

Compile time is most of this file's cost: the parity sets share one model structure (every
parameter given; Mitsuba's value with a parameter given as 0 is the value without it), and the
parity, pdf, reciprocity, finite-difference and hard-case tests share one jitted program per
dtype (:func:`_probe`) on one set of directions: the 300 parity pairs followed by the hard
pairs (weighted 0 in the finite differences).
"""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import SampleOnePdfOther, assert_finite, central_differences, eval_jit, seed_of

import brdf_fit as bf
from brdf_fit.core.frame import unit_from_angles
from brdf_fit.data import GonioData
from brdf_fit.models.mitsuba_principled import (
    MITSUBA_DEFAULTS,
    MitsubaPrincipled,
    eta_from_specular,
    registry_entries,
    specular_from_eta,
    to_mitsuba_dict,
)
from brdf_fit.verify.chi2 import chi2_test_brdf

EPS32 = float(np.finfo(np.float32).eps)
#: float32 epsilons allowed per lane (measured worst without clearcoat 7 eps = 8.0e-7, typical
#: 1-4 eps)
PARITY_ULPS = 32
#: float32 epsilons of asymmetry allowed on float32-rounded directions (measured in Mitsuba:
#: 2.6e-6 .. 4.2e-6 = 22 .. 35 eps over four sets, at near-opposite grazing pairs, where the
#: rounding of |wi| and |wo| moves wi.h against wo.h by (|wo|^2 - |wi|^2) / |wi + wo|)
RECIPROCITY_ULPS = 64

PARITY_SETS = {
    "isotropic": dict(base_color=[0.8, 0.3, 0.1], roughness=0.4, metallic=0.2),
    "aniso-metal-tint": dict(base_color=[0.8, 0.3, 0.1], roughness=0.3, metallic=0.7,
                             anisotropic=0.6, spec_tint=0.4, specular=0.7),
    "aniso-max-smooth": dict(base_color=[0.3, 0.7, 0.9], roughness=0.15, anisotropic=1.0,
                             specular=1.0),
    "metal-mix": dict(base_color=[0.95, 0.64, 0.54], roughness=0.25, metallic=0.5,
                      specular=0.3, spec_tint=1.0),
    "sheen-flat": dict(base_color=[0.2, 0.6, 0.3], roughness=0.6, sheen=0.8, sheen_tint=0.5,
                       flatness=0.4),
    "clearcoat": dict(base_color=[0.2, 0.6, 0.3], roughness=0.6, clearcoat=0.9,
                      clearcoat_gloss=0.3),
    "everything": dict(base_color=[0.9, 0.9, 0.2], roughness=0.1, metallic=0.35, specular=0.8,
                       spec_tint=0.3, anisotropic=0.8, sheen=1.0, sheen_tint=1.0, clearcoat=1.0,
                       clearcoat_gloss=1.0, flatness=1.0),
    "roughness-0-metal": dict(base_color=[0.5, 0.5, 0.9], roughness=0.0, metallic=1.0),
    "specular-0": dict(base_color=[0.5, 0.5, 0.9], roughness=0.5, specular=0.0, metallic=0.5),
    "black-tinted": dict(base_color=[0.0, 0.0, 0.0], roughness=0.7, spec_tint=1.0, sheen=0.5,
                         sheen_tint=1.0),
}


def _unit(z, phi):
    s = np.sqrt(1.0 - np.asarray(z) ** 2)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z * np.ones_like(s)], -1)


def parity_pairs():
    """200 random pairs (cosines uniform in [0.01, 1]) and 100 grazing ones (one or both
    cosines log-uniform in [1e-3, 0.05]), rounded to float32 (what Mitsuba sees)."""
    rng = np.random.default_rng(seed_of("mitsuba-principled-parity"))
    wi = _unit(rng.uniform(0.01, 1.0, 200), rng.uniform(0, 2 * np.pi, 200))
    wo = _unit(rng.uniform(0.01, 1.0, 200), rng.uniform(0, 2 * np.pi, 200))
    zi = 10 ** rng.uniform(-3, math.log10(0.05), 100)
    zo = np.concatenate([10 ** rng.uniform(-3, math.log10(0.05), 50), rng.uniform(0.05, 1, 50)])
    gi = _unit(zi, rng.uniform(0, 2 * np.pi, 100))
    go = _unit(zo, rng.uniform(0, 2 * np.pi, 100))
    swap = rng.uniform(size=100) < 0.5  # the grazing one on either side
    gi[swap], go[swap] = go[swap].copy(), gi[swap].copy()
    wi, wo = np.concatenate([wi, gi]), np.concatenate([wo, go])
    return wi.astype(np.float32).astype(float), wo.astype(np.float32).astype(float)


def full(p):
    """``p`` with every parameter given (Mitsuba's defaults for the rest)."""
    out = {k: v for k, v in MITSUBA_DEFAULTS.items()}
    out["base_color"] = [MITSUBA_DEFAULTS["base_color"]] * 3
    out.update(p)
    return out


def build(p, dtype=jnp.float64):
    return MitsubaPrincipled(**{k: jnp.asarray(v, dtype) for k, v in p.items()})


def f_pdf_of(p, wi, wo, dtype=jnp.float64):
    """``(f, pdf)`` of the full parameter set ``p`` at ``N_PARITY`` NumPy direction pairs,
    through :func:`_probe` with the hard pairs appended (the program the gradient and hard-case
    tests compile anyway: one compilation per dtype serves the whole file)."""
    hi, ho = hard_pairs()
    f, pdf, _, _ = _probe(_params(p, dtype), jnp.asarray(np.concatenate([wi, hi]), dtype),
                          jnp.asarray(np.concatenate([wo, ho]), dtype),
                          jnp.ones((len(wi) + len(hi), 3), dtype))
    return np.asarray(f)[:len(wi)], np.asarray(pdf)[:len(wi)]


def f_of(p, wi, wo, dtype=jnp.float64):
    return f_pdf_of(p, wi, wo, dtype)[0]


def mitsuba_f(p, wi, wo):
    pytest.importorskip("mitsuba")
    from brdf_fit.convert.mitsuba import mitsuba_eval

    return mitsuba_eval(to_mitsuba_dict(p), wi, wo)


def mitsuba_pdf(p, wi, wo):
    """Mitsuba's ``BSDF.pdf`` at our directions (the conventions of ``mitsuba_eval``)."""
    mi = pytest.importorskip("mitsuba")
    prev = mi.variant()
    mi.set_variant("scalar_rgb")
    try:
        bsdf = mi.load_dict(to_mitsuba_dict(p))
        ctx = mi.BSDFContext()
        out = np.zeros(len(wi))
        for n in range(len(wi)):
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*(float(x) for x in wo[n]))
            si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
            out[n] = bsdf.pdf(ctx, si, mi.Vector3f(*(float(x) for x in wi[n])))
    finally:
        if prev is not None and prev != "scalar_rgb":
            mi.set_variant(prev)
    return out


def clearcoat_conditioning(p, wi, wo):
    """``(n.h)^2 / (1 + (a^2 - 1)(n.h)^2)``: the relative float32 error Mitsuba's GTR1
    denominator has, in units of eps."""
    a = 0.1 + (0.001 - 0.1) * p.get("clearcoat_gloss", 0.0)
    h = wi + wo
    hz2 = h[:, 2] ** 2 / np.sum(h * h, -1)
    return hz2 / (1.0 + (a * a - 1.0) * hz2)


# ----------------------------------------------------------------------------- parity


@pytest.mark.parametrize("case", list(PARITY_SETS))
def test_eval_matches_mitsuba(case):
    p = full(PARITY_SETS[case])
    wi, wo = parity_pairs()
    ref = mitsuba_f(p, wi, wo)
    assert np.all(ref > 0)
    f = f_of(p, wi, wo)
    tol = PARITY_ULPS * EPS32 * np.ones_like(ref)
    if p["clearcoat"] > 0:
        share = 1.0 - f_of({**p, "clearcoat": 0.0}, wi, wo) / f
        tol = tol + 4 * EPS32 * clearcoat_conditioning(p, wi, wo)[:, None] * share
    rel = np.abs(f - ref) / ref
    worst = np.unravel_index(np.argmax(rel / tol), rel.shape)
    assert np.all(rel <= tol), (case, rel.max(), worst, wi[worst[0]], wo[worst[0]])
    # the float32 model: the same parity with its own rounding on top
    f32 = f_of(p, wi, wo, jnp.float32)
    assert np.all(np.abs(f32 - ref) / ref <= 2 * tol), case


def test_defaults_are_mitsubas():
    """The bare plugin (nothing given), the bare model and every registry entry at its
    defaults (each its own structure: parameters not given are not traced) agree."""
    wi, wo = parity_pairs()
    ref = mitsuba_f({}, wi, wo)
    for e in registry_entries():
        assert {p.name: float(np.ravel(p.default_value())[0]) for p in e.params} == {
            p.name: MITSUBA_DEFAULTS[p.name] for p in e.params}
        f = np.asarray(eval_jit(e.build(), jnp.asarray(wi), jnp.asarray(wo)))
        assert np.max(np.abs(f - ref) / ref) < PARITY_ULPS * EPS32, e.name
        assert mitsuba_f(e.defaults(), wi[:20], wo[:20]) == pytest.approx(ref[:20], rel=1e-7)
    bare = MitsubaPrincipled()  # the class's own defaults: Mitsuba's, optional lobes absent
    assert bare.given() == {k: MITSUBA_DEFAULTS[k] for k in
                            ("base_color", "roughness", "metallic", "specular")}


@pytest.mark.parametrize("case", ["aniso-metal-tint", "everything"])
def test_pdf_matches_mitsuba(case):
    """The pdf (our sampler's exact density) is Mitsuba's ``Principled::pdf``, to the same
    tolerance as ``f`` (with the clearcoat term's share of the pdf)."""
    p = full(PARITY_SETS[case])
    wi, wo = parity_pairs()
    ref = mitsuba_pdf(p, wi, wo)
    model = build(p)
    got = f_pdf_of(p, wi, wo)[1]
    tol = PARITY_ULPS * EPS32 * np.ones(len(wi))
    if p["clearcoat"] > 0:
        _, pc, _ = (float(x) for x in model.lobe_probabilities())
        a2 = float(model.clearcoat_alpha()) ** 2
        h = (wi + wo) / np.linalg.norm(wi + wo, axis=-1, keepdims=True)
        d_gtr1 = (a2 - 1.0) / (np.pi * np.log(a2) * (1.0 + (a2 - 1.0) * h[:, 2] ** 2))
        share = pc * d_gtr1 * h[:, 2] / (4.0 * np.sum(wi * h, -1)) / ref
        tol = tol + 4 * EPS32 * clearcoat_conditioning(p, wi, wo) * share
    rel = np.abs(got - ref) / ref
    assert np.all(rel <= tol), (rel.max(), np.argmax(rel / tol))


def test_mitsuba_departures_from_burley_are_reproduced():
    """Negative controls of the parity test: (1) ``specular = 0`` switches Mitsuba's whole
    specular lobe off (metallic part included): the value jumps between 0 and 1e-3, and the
    model with it; (2) Mitsuba's clearcoat lacks Burley's ``1/(4 ci co)``: with it the parity
    fails by far."""
    wi, wo = parity_pairs()
    p0 = full(PARITY_SETS["specular-0"])
    p1 = {**p0, "specular": 1e-3}
    r0, r1 = mitsuba_f(p0, wi, wo), mitsuba_f(p1, wi, wo)
    assert np.max(r1 / r0) > 10.0
    for p, r in ((p0, r0), (p1, r1)):
        assert np.max(np.abs(f_of(p, wi, wo) - r) / r) < PARITY_ULPS * EPS32
    pc = full(PARITY_SETS["clearcoat"])
    ref = mitsuba_f(pc, wi, wo)
    f, f_base = f_of(pc, wi, wo), f_of({**pc, "clearcoat": 0.0}, wi, wo)
    burley = f_base + (f - f_base) / (4.0 * wi[:, 2:3] * wo[:, 2:3])
    assert np.max(np.abs(burley - ref) / ref) > 0.1


def test_reciprocity_model_and_mitsuba():
    """Mitsuba's float32 evaluation is reciprocal to its rounding on float32 directions; the
    model shows the same asymmetry there (it reads ``wi.h`` and ``wo.h`` where Mitsuba does:
    they differ for directions unit only to rounding) and none on unit directions."""
    wi, wo = parity_pairs()
    p = full(PARITY_SETS["everything"])
    ra, rb = mitsuba_f(p, wi, wo), mitsuba_f(p, wo, wi)
    assert np.max(np.abs(ra - rb) / ra) < RECIPROCITY_ULPS * EPS32
    a, b = f_of(p, wi, wo), f_of(p, wo, wi)
    assert np.max(np.abs(a - b) / a) < RECIPROCITY_ULPS * EPS32
    wi, wo = (w / np.linalg.norm(w, axis=-1, keepdims=True) for w in (wi, wo))
    a, b = f_of(p, wi, wo), f_of(p, wo, wi)
    assert np.max(np.abs(a - b) / a) < 1e-13


def test_to_mitsuba_dict_and_eta():
    d = to_mitsuba_dict({"base_color": 0.25, "roughness": np.float64(0.3)})
    assert d == {"type": "principled", "base_color": {"type": "rgb", "value": [0.25] * 3},
                 "roughness": 0.3}
    with pytest.raises(ValueError):
        to_mitsuba_dict({"alpha": 0.3})
    m = build(PARITY_SETS["clearcoat"])
    assert set(to_mitsuba_dict(m.given())) == {"type", "base_color", "roughness", "metallic",
                                                "specular", *PARITY_SETS["clearcoat"]}
    s = np.linspace(0.0, 1.0, 11)
    eta = np.asarray(jax.jit(eta_from_specular)(s))
    assert eta[5] == pytest.approx(1.5, rel=1e-12) and eta[0] == 1.0
    assert np.allclose(np.asarray(jax.jit(specular_from_eta)(eta)), s, rtol=0, atol=1e-14)


# ----------------------------------------------------------------------------- derivatives

GRAD_PARAMS = dict(base_color=[0.6, 0.4, 0.2], roughness=0.45, metallic=0.3, specular=0.6,
                   spec_tint=0.35, anisotropic=0.4, sheen=0.5, sheen_tint=0.3, clearcoat=0.6,
                   clearcoat_gloss=0.4, flatness=0.3)

#: hard parameter sets (each applied over GRAD_PARAMS): roughness 0 (alpha at Mitsuba's floor
#: 1e-3), anisotropic 1, gloss 1 (GTR1 alpha 1e-3), specular 0 (lobe off), black base colour
#: (luminance 0), every parameter at 1, every one at 0
HARD_SETS = [
    dict(roughness=0.0, anisotropic=1.0, clearcoat=1.0, clearcoat_gloss=1.0, metallic=0.0),
    dict(roughness=0.0, metallic=1.0, specular=1.0, spec_tint=1.0),
    dict(roughness=1.0, anisotropic=1.0, sheen=1.0, sheen_tint=1.0, flatness=1.0),
    dict(specular=0.0, metallic=0.5, clearcoat=1.0, clearcoat_gloss=0.0),
    dict(base_color=[0.0, 0.0, 0.0], spec_tint=1.0, sheen=1.0, sheen_tint=1.0),
    {k: ([1.0] * 3 if k == "base_color" else 1.0) for k in GRAD_PARAMS},
    {k: ([0.0] * 3 if k == "base_color" else 0.0) for k in GRAD_PARAMS},
]


def hard_pairs():
    """Grazing (1e-6) against 1e-6 .. 1 at three azimuth relations (opposite grazing pairs:
    the half vector vanishes in the limit), wi = wo at normal incidence and grazing, mirror
    pairs."""
    cs = (1e-6, 1e-3, 0.5, 1.0)
    wi, wo = [], []
    for ci in cs:
        for co in cs:
            for pi_, po in ((0.3, 2.1), (0.7, 0.7), (0.0, math.pi)):
                wi.append(_unit(ci, pi_))
                wo.append(_unit(co, po))
    for c in cs:
        w = _unit(c, 0.7)
        wi += [w, w * np.array([-1.0, -1.0, 1.0])]
        wo += [w, w]
    return np.asarray(wi), np.asarray(wo)


def probe_pairs():
    """The parity pairs followed by the hard pairs, and the mask of the parity ones."""
    wi, wo = parity_pairs()
    hi, ho = hard_pairs()
    return (np.concatenate([wi, hi]), np.concatenate([wo, ho]),
            np.arange(len(wi) + len(hi)) < len(wi))


@jax.jit
def _probe(p, wi, wo, wf):
    """``f``, pdf, ``sum(f wf)`` and its gradient in ``(p, wi, wo)`` (the pdf's gradient is
    the registry hard-case check's business: this file keeps to one compilation per dtype)."""

    def total(p, wi, wo):
        return jnp.sum(MitsubaPrincipled(**p).eval(wi, wo) * wf)

    value, grads = jax.value_and_grad(total, argnums=(0, 1, 2))(p, wi, wo)
    m = MitsubaPrincipled(**p)
    return m.eval(wi, wo), m.pdf(wi, wo), value, grads


@jax.jit
def _draw(p, wo, uc, u):
    s = MitsubaPrincipled(**p).sample(wo, uc, u)
    return s.wi, s.pdf, s.weight


def _params(p, dtype):
    return {k: jnp.asarray(v, dtype) for k, v in p.items()}


def test_gradients_match_finite_differences():
    """Every parameter (each base_color channel) against central differences in float64
    (step 1e-6) of a weighted sum of f over the 300 parity pairs (grazing ones included)."""
    WI, WO, generic = probe_pairs()
    rng = np.random.default_rng(seed_of("mitsuba-principled-weights"))
    wf = jnp.asarray(rng.uniform(0.5, 1.5, (len(WI), 3)) * generic[:, None])
    wi, wo = jnp.asarray(WI), jnp.asarray(WO)
    p0 = {k: np.asarray(v, float) for k, v in GRAD_PARAMS.items()}
    grads = _probe(_params(p0, jnp.float64), wi, wo, wf)[3][0]
    fd = central_differences(
        lambda q: float(_probe(_params(q, jnp.float64), wi, wo, wf)[2]), p0, h=1e-6)
    for (name,), d in fd.items():
        g = np.asarray(grads[name]).reshape(d.shape)
        np.testing.assert_allclose(g, d, rtol=1e-6, atol=1e-8, err_msg=name)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64], ids=["f32", "f64"])
def test_hard_cases_values_and_gradients_finite(dtype):
    """Values, pdfs and gradients of f (parameters and both directions) finite and non-negative at
    the hard pairs for every hard set; samples at grazing (1e-6), oblique and normal views with
    uniforms at 0, 1e-7, 0.5 and 1 - 1e-7 finite, a failure with pdf 0 and weight 0; below the
    horizon f = pdf = 0 and sampling fails."""
    WI, WO, _ = probe_pairs()
    wi, wo = jnp.asarray(WI, dtype), jnp.asarray(WO, dtype)
    ones_f = jnp.ones((len(WI), 3), dtype)
    views = np.stack([_unit(c, 0.4) for c in (1e-6, 0.5, 1.0)])
    us = np.asarray((0.0, 1e-7, 0.5, 1 - 1e-7))
    u = np.stack(np.meshgrid(us, us), -1).reshape(-1, 2)
    uc = np.linspace(0.0, 1 - 1e-7, 16)
    w_s = jnp.asarray(np.repeat(views, 16, axis=0), dtype)
    u_s, uc_s = jnp.asarray(np.tile(u, (3, 1)), dtype), jnp.asarray(np.tile(uc, 3), dtype)
    for hard in HARD_SETS:
        p = _params({**GRAD_PARAMS, **hard}, dtype)
        f, pdf, _, grads = _probe(p, wi, wo, ones_f)
        what = f"{hard} {jnp.dtype(dtype).name}"
        assert_finite((f, pdf, grads), what)
        assert np.all(np.asarray(f) >= 0) and np.all(np.asarray(pdf) >= 0), what
        s_wi, s_pdf, s_w = _draw(p, w_s, uc_s, u_s)
        assert_finite((s_wi, s_pdf, s_w), what)
        s_pdf, s_w = np.asarray(s_pdf), np.asarray(s_w)
        assert np.all(s_pdf >= 0) and np.all(s_w[s_pdf == 0] == 0), what
    below = jnp.asarray(np.tile([[0.6, 0.0, -0.8]], (len(WI), 1)), dtype)
    p = _params(GRAD_PARAMS, dtype)
    assert not np.any(np.asarray(_probe(p, below, wo, ones_f)[0]))
    assert not np.any(np.asarray(_probe(p, wi, below, ones_f)[1]))
    _, s_pdf, s_w = _draw(p, jnp.asarray(np.tile([[0.6, 0.0, -0.8]], (48, 1)), dtype), uc_s, u_s)
    assert not np.any(np.asarray(s_pdf)) and not np.any(np.asarray(s_w))


# ----------------------------------------------------------------------------- sampling

CHI2_VIEWS = (0.7, 0.15)


#: three lobes drawn: diffuse, clearcoat, anisotropic GGX. (At roughness 0.3 the histogram is
#: chi2's lobe grid about the mirror direction, whose adaptive cell integration of the
#: clearcoat's sharp GTR1 core cost 6-37 s a view; at 0.4 it is the sphere grid, ~1 s.)
CHI2_PARAMS = dict(base_color=[0.8, 0.3, 0.1], roughness=0.4, metallic=0.4, anisotropic=0.5,
                   clearcoat=0.6, clearcoat_gloss=0.5)


def _chi2(model, cos_o, seed):
    return chi2_test_brdf(model, jnp.asarray(_unit(cos_o, 0.4)), n_samples=100_000, seed=seed,
                          test_count=len(CHI2_VIEWS) + 1, cell_nodes=8)


@pytest.mark.parametrize("cos_o", CHI2_VIEWS)
def test_sampler_matches_pdf_chi2(cos_o):
    """Two views; Sidak-corrected over them and the negative control."""
    r = _chi2(build(CHI2_PARAMS), cos_o, seed_of("mitsuba-principled", cos_o))
    assert r.passed, f"{r}\n{r.worst_cells(6)}"


def test_chi2_rejects_wrong_lobe_probabilities():
    """Negative control: a pdf that doubles the clearcoat's sampling rate (its lobe
    probability 0.086 -> 0.158) must fail the same test."""
    model = build(CHI2_PARAMS)
    other = dataclasses.replace(model, clearcoat_sampling_rate=2.0)
    r = _chi2(SampleOnePdfOther(model, other), CHI2_VIEWS[0], seed_of("mitsuba-neg"))
    assert not r.passed


# ----------------------------------------------------------------------------- recovery


def test_recovers_parameters_from_mitsuba_data():
    """Noise-free Mitsuba data on a 9 x 8 x 6 (theta_i, theta_o, phi_o) grid (432 pairs): the
    built model (the ``mitsuba-principled`` structure with spec_tint not given) fitted from
    a start inside the intervals with base_color, roughness, metallic, specular free."""
    truth = dict(base_color=[0.7, 0.35, 0.15], roughness=0.35, metallic=0.3, specular=0.6)
    ti, to, po = np.meshgrid(np.linspace(0, 80, 9), np.linspace(5, 85, 8),
                             np.linspace(0, 180, 6), indexing="ij")
    wi = unit_from_angles(ti.ravel(), np.zeros(ti.size))
    wo = unit_from_angles(to.ravel(), po.ravel() + 180.0)
    data = GonioData(wi=wi, wo=wo, value=mitsuba_f(truth, wi, wo), channels=("R", "G", "B"))
    start = build(dict(base_color=[0.5] * 3, roughness=0.5, metallic=0.5, specular=0.5))
    r = bf.fit(data, start, guess="none")
    assert r.converged
    for k, v in truth.items():
        np.testing.assert_allclose(np.asarray(r.params[k]), v, rtol=0, atol=1e-5, err_msg=k)

