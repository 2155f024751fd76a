"""Noise and calibration models: the documented statistics (fixed seeds, a few thousand samples,
4-standard-error bounds), sigma estimates, per-channel gain, jitter geometry, and the
pipeline's determinism and stream separation."""

import math

import numpy as np
import pytest

from data_synth.noise import (
    AngularJitter,
    Dark,
    Gain,
    Lognormal,
    NoiseError,
    Shot,
    make_noise,
    run_pipeline,
)
from data_synth.plans import random_sparse, unit_from_angles

N = 4000


def _dirs(n=N, seed=0, max_zenith=80.0):
    return tuple(random_sparse(n, seed=seed, max_zenith_deg=max_zenith))


def _const(values):
    values = np.asarray(values, float)
    return lambda wi, wo: np.broadcast_to(values, (wi.shape[0], values.size)).copy()


def _apply(model, values, seed=0, wo=None, sigma=None, truth=None):
    n = values.shape[0]
    wi = np.tile([0.0, 0.0, 1.0], (n, 1))
    wo = wi if wo is None else wo
    return model.apply(values, sigma, wi, wo, np.random.default_rng(seed),
                       {} if truth is None else truth)


def test_lognormal_statistics_and_sigma():
    s = 0.3
    v = np.full((N, 3), 2.0)
    out, sig = _apply(Lognormal(s), v, seed=1)
    r = np.log(out / v).ravel()
    m = r.size
    # log(v'/v) ~ N(0, s): mean 0 (se s/sqrt m), std s (se ~ s/sqrt(2m))
    assert abs(r.mean()) < 4 * s / math.sqrt(m)
    assert abs(r.std() - s) < 4 * s / math.sqrt(2 * m)
    # median preserving, so the mean is biased up by exp(s^2/2) (1.046 here)
    mean_ratio = (out / v).mean()
    se = math.sqrt((math.exp(s * s) - 1) * math.exp(s * s)) / math.sqrt(m)
    assert abs(mean_ratio - math.exp(s * s / 2)) < 4 * se
    assert abs(mean_ratio - 1.0) > 10 * se
    assert abs(np.median(out / v) - 1.0) < 0.02
    # the sigma estimate is s |v'|; an incoming sigma is scaled by the factor and added in
    # quadrature
    np.testing.assert_allclose(sig, s * np.abs(out), rtol=1e-15)
    prev = np.full_like(v, 0.05)
    out2, sig2 = _apply(Lognormal(s), v, seed=1, sigma=prev)
    np.testing.assert_array_equal(out2, out)
    np.testing.assert_allclose(sig2, np.hypot(prev * out / v, s * out), rtol=1e-14)
    # sigma = 0 is the identity
    out0, _ = _apply(Lognormal(0.0), v, seed=1)
    np.testing.assert_array_equal(out0, v)


def test_shot_noise_is_poisson_in_detected_flux():
    ppu = 200.0
    wo = unit_from_angles(np.where(np.arange(N) % 2 == 0, 0.0, 60.0), 0.0)  # cos 1 and 0.5
    v = np.full((N, 1), 0.5)
    out, sig = _apply(Shot(ppu), v, seed=2, wo=wo)
    scale = wo[:, 2:3] * ppu
    counts = out * scale
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)  # whole photons
    for cos in (1.0, 0.5):
        sel = np.isclose(wo[:, 2], cos)
        lam = 0.5 * cos * ppu
        c = counts[sel, 0]
        k = c.size
        assert abs(c.mean() - lam) < 4 * math.sqrt(lam / k)
        # Poisson: variance = mean (se of the sample variance ~ lam sqrt(2/k) for large lam)
        assert abs(c.var() / lam - 1.0) < 4 * math.sqrt(2.0 / k)
    np.testing.assert_allclose(sig, np.sqrt(np.maximum(counts, 1.0)) / scale, rtol=1e-14)
    # negative inputs (after dark noise) count as zero photons; sigma is one photon
    neg, sneg = _apply(Shot(ppu), np.full((5, 1), -0.1), seed=0)
    np.testing.assert_array_equal(neg, 0.0)
    np.testing.assert_allclose(sneg, 1.0 / ppu)
    with pytest.raises(NoiseError, match="photons_per_unit must be > 0"):
        Shot(0.0)


def test_dark_noise_is_additive_gaussian():
    s = 0.01
    v = np.full((N, 2), 0.003)
    out, sig = _apply(Dark(s), v, seed=3)
    d = (out - v).ravel()
    assert abs(d.mean()) < 4 * s / math.sqrt(d.size)
    assert abs(d.std() - s) < 4 * s / math.sqrt(2 * d.size)
    assert (out < 0).any()  # measured values may be slightly negative
    np.testing.assert_array_equal(sig, s)
    # independent of the signal level
    out_big, _ = _apply(Dark(s), v + 10.0, seed=3)
    np.testing.assert_allclose(out_big - (v + 10.0), out - v, atol=1e-12)


def test_gain_is_one_factor_per_channel():
    rng = np.random.default_rng(4)
    v = rng.uniform(0.1, 1.0, (50, 3))
    truth = {}
    prev = np.full_like(v, 0.02)
    out, sig = _apply(Gain(0.1), v, seed=4, sigma=prev, truth=truth)
    g = out / v
    # the same factor for every sample of a channel, different factors across channels
    np.testing.assert_allclose(g, np.broadcast_to(g[0], g.shape), rtol=1e-14)
    assert len(set(np.round(g[0], 12))) == 3
    np.testing.assert_allclose(truth["gain"], g[0], rtol=1e-14)
    np.testing.assert_allclose(sig, prev * g[0], rtol=1e-14)  # scales sigma, adds none
    _, none = _apply(Gain(0.1), v, seed=4)
    assert none is None
    # two gain stages compound in the recorded truth
    _apply(Gain(0.1), v, seed=5, truth=truth)
    g2 = np.exp(0.1 * np.random.default_rng(5).standard_normal(3))
    np.testing.assert_allclose(truth["gain"], g[0] * g2, rtol=1e-14)
    # the log gains are N(0, sigma) across datasets
    logs = np.array([np.log(_apply(Gain(0.1), v[:1], seed=s)[0][0] / v[0])
                     for s in range(1000)]).ravel()
    assert abs(logs.mean()) < 4 * 0.1 / math.sqrt(logs.size)
    assert abs(logs.std() - 0.1) < 4 * 0.1 / math.sqrt(2 * logs.size)


@pytest.mark.parametrize("theta", [0.0, 30.0, 89.5])
def test_jitter_keeps_unit_vectors_above_horizon(theta):
    sig_deg = 1.0
    w = unit_from_angles(np.full(N, theta), np.linspace(0, 360, N, endpoint=False))
    wi2, wo2 = AngularJitter(sig_deg).perturb(w, w, np.random.default_rng(6))
    for out in (wi2, wo2):
        np.testing.assert_allclose(np.linalg.norm(out, axis=-1), 1.0, atol=1e-14)
        assert (out[:, 2] > 0).all()
    assert not np.array_equal(wi2, wo2)  # the two arms err independently
    ang = np.arccos(np.clip(np.sum(wi2 * w, -1), -1, 1))
    if theta < 80:
        # isotropic tangent error with sd s per axis: E[angle^2] = 2 s^2 (Rayleigh),
        # Var[angle^2] = 4 s^4
        s = math.radians(sig_deg)
        assert abs(np.mean(ang**2) - 2 * s * s) < 4 * 2 * s * s / math.sqrt(N)
    else:
        assert ang.max() < math.radians(6 * sig_deg)  # reflection never makes it larger
    same, _ = AngularJitter(0.0).perturb(w, w, np.random.default_rng(0))
    np.testing.assert_allclose(same, w, atol=1e-15)


# ----------------------------------------------------------------------------- pipeline


def test_pipeline_is_deterministic_from_the_seed():
    wi, wo = _dirs(300)
    models = [AngularJitter(0.2), Lognormal(0.05), Shot(1e3), Dark(1e-3), Gain(0.03)]

    def evaluate(a, b):
        return np.stack([a[:, 2] * b[:, 2], 0.5 + 0 * a[:, 0], a[:, 0] ** 2], -1)

    r1 = run_pipeline(models, wi, wo, evaluate, seed=42)
    r2 = run_pipeline([m.spec() for m in models], wi, wo, evaluate, seed=42)
    for a, b in zip(r1[:3], r2[:3], strict=True):
        np.testing.assert_array_equal(a, b)
    assert r1[3] == r2[3]
    r3 = run_pipeline(models, wi, wo, evaluate, seed=43)
    assert not np.array_equal(r1[1], r3[1])
    assert r1[3]["gain"] != r3[3]["gain"]


def test_pipeline_order_streams_and_sigma():
    wi, wo = _dirs(500)
    v = np.array([0.2, 0.4, 0.8])
    seed = 9
    clean, values, sigma, truth = run_pipeline([Lognormal(0.1), Dark(0.01)], wi, wo,
                                               _const(v), seed)
    # documented streams: SeedSequence(seed).spawn(n)[position], value models in list order
    s0, s1 = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    after_log = v * np.exp(0.1 * s0.standard_normal((500, 3)))
    want = after_log + 0.01 * s1.standard_normal((500, 3))
    np.testing.assert_array_equal(clean, np.broadcast_to(v, (500, 3)))
    np.testing.assert_allclose(values, want, rtol=1e-15)
    np.testing.assert_allclose(sigma, np.hypot(0.1 * np.abs(after_log), 0.01), rtol=1e-14)
    assert truth == {}
    # changing one stage's parameters does not reshuffle the others' noise
    _, va, _, ta = run_pipeline([Gain(0.05), Dark(0.01)], wi, wo, _const(v), seed)
    _, vb, _, tb = run_pipeline([Gain(0.2), Dark(0.01)], wi, wo, _const(v), seed)
    np.testing.assert_allclose(va - v * np.array(ta["gain"]), vb - v * np.array(tb["gain"]),
                               atol=1e-15)
    # no value model: no sigma, values are the clean ones
    c, vals, sig, _ = run_pipeline([], wi, wo, _const(v), seed)
    assert sig is None
    np.testing.assert_array_equal(vals, c)


def test_jitter_moves_the_evaluation_not_the_nominal_directions():
    wi, wo = _dirs(200)
    seen = []

    def evaluate(a, b):
        seen.append((a, b))
        return a[:, 2:3] * b[:, 2:3]

    clean, values, sigma, _ = run_pipeline([AngularJitter(0.5)], wi, wo, evaluate, seed=1)
    a, b = seen[0]
    assert not np.allclose(a, wi) and not np.allclose(b, wo)
    np.testing.assert_allclose(np.arccos(np.clip(np.sum(a * wi, -1), -1, 1)).max(),
                               0.0, atol=math.radians(5 * 0.5))
    np.testing.assert_array_equal(clean, values)  # jitter adds no value noise
    assert sigma is None
    np.testing.assert_allclose(clean[:, 0], a[:, 2] * b[:, 2])
    # jitter draws from its own stream: adding a value stage after it keeps the same directions
    seen.clear()
    run_pipeline([AngularJitter(0.5), Dark(0.1)], wi, wo, evaluate, seed=1)
    np.testing.assert_array_equal(seen[0][0], a)


def test_make_noise_specs_aliases_and_errors():
    for m in (Lognormal(0.02), Shot(50.0), Dark(0.5), Gain(0.1), AngularJitter(0.3)):
        assert make_noise(m.spec()) == m
        assert make_noise(m) is m
    assert make_noise({"type": "Poisson", "photons_per_unit": 10}) == Shot(10.0)
    assert make_noise({"type": "jitter", "args": {"sigma_deg": 2}}) == AngularJitter(2.0)
    assert make_noise({"type": "multiplicative"}) == Lognormal()
    with pytest.raises(NoiseError, match=r"unknown noise type 'speckle'; valid types: lognormal"):
        make_noise({"type": "speckle"})
    with pytest.raises(NoiseError, match=r"noise 'dark': unknown argument\(s\) 'mu'; valid "
                                         r"arguments: sigma"):
        make_noise({"type": "dark", "mu": 1})
    with pytest.raises(NoiseError, match="must be a table/dict with a 'type' key"):
        make_noise("lognormal")
    with pytest.raises(NoiseError, match=r"lognormal: sigma must be finite and >= 0"):
        make_noise({"type": "lognormal", "sigma": -0.1})
    with pytest.raises(NoiseError, match=r"gain: sigma must be finite and >= 0, got 'big'"):
        make_noise({"type": "gain", "sigma": "big"})
    with pytest.raises(NoiseError, match=r"'args' must be a table/dict"):
        make_noise({"type": "gain", "args": [0.1]})
