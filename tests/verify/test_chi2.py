"""Tests of brdf_fit.verify.chi2: correct samplers pass, broken ones (negative controls) fail.

The samplers live here, written independently of the library: a cosine-weighted hemisphere, the
uniform sphere, and a Phong (power-cosine) lobe about an axis tilted 60 degrees from the normal
whose samples below the horizon fail (pdf 0). Every sampler is jitted once (module-level cache);
``chi2_test`` pads its chunks to one shape, so each compiles once.
"""

from __future__ import annotations

import functools
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from brdf_fit.core.quadrature import composite_gauss_legendre_hemisphere, integrate
from brdf_fit.verify import chi2

N = 100_000
TILT = math.radians(60.0)
EXPONENT = 20


# --------------------------------------------------------------------------------------------
# Reference samplers
# --------------------------------------------------------------------------------------------


def _from_local(cos_t, phi):
    sin_t = jnp.sqrt(jnp.clip(1.0 - cos_t * cos_t, 0.0, None))
    return jnp.stack([sin_t * jnp.cos(phi), sin_t * jnp.sin(phi), cos_t], axis=-1)


@jax.jit
def cosine_sample(u):
    cos_t = jnp.sqrt(u[:, 0])
    return _from_local(cos_t, 2.0 * jnp.pi * u[:, 1]), cos_t / jnp.pi


@jax.jit
def cosine_pdf(wi):
    return jnp.where(wi[:, 2] > 0.0, wi[:, 2] / jnp.pi, 0.0)


@jax.jit
def cosine_pdf_scaled(wi):
    return 1.1 * cosine_pdf(wi)


@jax.jit
def sphere_sample(u):
    cos_t = 1.0 - 2.0 * u[:, 0]
    return _from_local(cos_t, 2.0 * jnp.pi * u[:, 1]), jnp.full_like(cos_t, 0.25 / jnp.pi)


@jax.jit
def sphere_pdf(wi):
    return jnp.full(wi.shape[:-1], 0.25 / jnp.pi, dtype=wi.dtype)


def _lobe_frame(tilt):
    axis = np.array([math.sin(tilt), 0.0, math.cos(tilt)])
    t = np.array([math.cos(tilt), 0.0, -math.sin(tilt)])
    b = np.cross(axis, t)
    return jnp.asarray(t), jnp.asarray(b), jnp.asarray(axis)


@functools.cache
def phong(n_sample=EXPONENT, n_pdf=EXPONENT, phi_max=2.0 * math.pi, tilt=TILT):
    """Power-cosine lobe about an axis tilted ``tilt`` from the normal; below-horizon samples fail.

    The sampler draws ``cos = u1^(1/(n_sample + 1))``, ``phi = phi_max u2`` about the axis; the pdf
    function is ``(n_pdf + 1)/(2 pi) cos^n_pdf`` above the horizon and 0 below. Correct when
    ``n_sample == n_pdf`` and ``phi_max == 2 pi``.
    """
    t, b, axis = _lobe_frame(tilt)

    def density(c):
        return (n_pdf + 1) / (2.0 * jnp.pi) * jnp.clip(c, 0.0, None) ** n_pdf

    @jax.jit
    def sample(u):
        cos_a = u[:, 0] ** (1.0 / (n_sample + 1))
        loc = _from_local(cos_a, phi_max * u[:, 1])
        wi = loc[:, :1] * t + loc[:, 1:2] * b + loc[:, 2:] * axis
        return wi, jnp.where(wi[:, 2] > 0.0, density(cos_a), 0.0)

    @jax.jit
    def pdf(wi):
        return jnp.where(wi[:, 2] > 0.0, density(wi @ axis), 0.0)

    return sample, pdf


def _critical(result):
    """The statistic above which ``result`` fails at its Sidak threshold (from SciPy)."""
    return stats.chi2.isf(result.threshold, result.dof)


# --------------------------------------------------------------------------------------------
# Distribution functions and pooling
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "stat, dof",
    [(0.01, 1), (3.84, 1), (0.5, 2), (10.0, 3), (7.0, 12), (150.0, 99), (90.0, 99), (250.0, 199)],
)
def test_p_value_matches_scipy(stat, dof):
    np.testing.assert_allclose(chi2.chi2_sf(stat, dof), stats.chi2.sf(stat, dof), rtol=1e-12)


@pytest.mark.parametrize("stat, dof", [(400.0, 100), (2000.0, 1500), (1e-3, 40), (900.0, 30)])
def test_p_value_matches_scipy_in_the_tails(stat, dof):
    np.testing.assert_allclose(chi2.chi2_sf(stat, dof), stats.chi2.sf(stat, dof), rtol=1e-10)


def test_p_value_edge_cases():
    assert chi2.chi2_sf(0.0, 5) == 1.0
    assert chi2.chi2_sf(math.inf, 5) == 0.0
    assert math.isnan(chi2.chi2_sf(3.0, 0))


def test_sidak_threshold():
    assert chi2.sidak_threshold(0.01, 1) == pytest.approx(0.01, rel=1e-14)
    for k in (2, 10, 1000):
        t = chi2.sidak_threshold(0.01, k)
        assert t == pytest.approx(1.0 - 0.99 ** (1.0 / k), rel=1e-10)
        assert 1.0 - (1.0 - t) ** k == pytest.approx(0.01, rel=1e-12)
    with pytest.raises(ValueError):
        chi2.sidak_threshold(0.0, 3)


def test_pooling_rule():
    obs = np.array([50.0, 30.0, 2.0, 1.0, 0.0, 0.0])
    exp = np.array([48.0, 33.0, 1.5, 2.0, 0.4, 0.0])
    stat, dof, n_pooled = chi2.pooled_chi2_statistic(obs, exp)
    # pooled bin: the three small cells (E = 3.9 < 5) absorb the smallest regular bin (33)
    pool_o, pool_e = 2.0 + 1.0 + 0.0 + 30.0, 1.5 + 2.0 + 0.4 + 33.0
    assert (dof, n_pooled) == (1, 4)
    assert stat == pytest.approx((50 - 48) ** 2 / 48 + (pool_o - pool_e) ** 2 / pool_e, rel=1e-14)
    # samples where the expectation is exactly zero make the statistic infinite
    stat, _, _ = chi2.pooled_chi2_statistic(obs + np.array([0, 0, 0, 0, 0, 3.0]), exp)
    assert stat == math.inf


def _terms_sum(r):
    """The statistic rebuilt from the result's report: unpooled cells, the pooled bin, and the
    failure category unless it is pooled."""
    contrib, pooled = r.contributions(), r.pooled_mask()
    pool_o, pool_e, n_pool = r.pooled_bin()
    total = float(np.sum(contrib[~pooled & (r.expected > 0.0)]))
    if n_pool:
        total += (pool_o - pool_e) ** 2 / pool_e
    if not r.fail_pooled():
        e_fail = r.expected_fail_fraction * r.n_samples
        total += (r.n_fail - e_fail) ** 2 / e_fail
    return total


def test_worst_cells_lists_the_terms_of_the_statistic_not_pooled_cells():
    """Regression: ``worst_cells`` ranked every cell by its own ``(O - E)^2 / E``, also cells that
    are pooled and enter the statistic only through the pooled bin. A cell with ``E = 0.19`` and
    ``O = 2`` then topped the table with 16.9 while the pooled bin it belonged to (``E = 8.3``,
    ``O = 12``) added 1.7, which sent the diagnosis of a failing test to the pooling rule."""
    observed = np.array([[2, 0, 480, 20_600], [1, 3_020, 5_200, 10_700]], dtype=np.int64)
    expected = np.array([[0.19, 2.5, 510.0, 20_500.0], [1.2, 3_000.0, 5_300.0, 10_000.0]])
    n = 50_000
    n_fail = n - int(observed.sum())
    e_fail = n - float(expected.sum())
    obs_cat = np.append(observed.reshape(-1), n_fail).astype(np.float64)
    exp_cat = np.append(expected.reshape(-1), e_fail)
    stat, dof, n_pooled = chi2.pooled_chi2_statistic(obs_cat, exp_cat)
    r = chi2.Chi2Result(
        statistic=stat, dof=dof, p_value=chi2.chi2_sf(stat, dof), threshold=0.01, passed=False,
        n_samples=n, fail_fraction=n_fail / n, expected_fail_fraction=e_fail / n,
        observed=observed, expected=expected, n_fail=n_fail, n_bins=dof + 1, n_pooled=n_pooled,
    )
    assert r.contributions()[0, 0] == pytest.approx((2 - 0.19) ** 2 / 0.19)  # 17.2, not a term
    rows = r.worst_cells(3).splitlines()[1:-1]
    assert len(rows) == 3
    assert rows[0].startswith("[+0.000,+1.000) [ 4.712, 6.283)")  # 700^2 / 10000 = 49
    # the pooled cell E = 0.19, O = 2 is not listed; the pooled bin (term 1.86) is third
    assert not any(row.startswith("[-1.000,+0.000) [ 0.000, 1.571)") for row in rows)
    pool_term = (483 - 513.89) ** 2 / 513.89
    assert rows[2].startswith("pooled bin (4 cells)") and f"{pool_term:.3g}" in rows[2]
    # the three cells with E < 5 (0.19 + 2.5 + 1.2 = 3.89) absorb the smallest regular cell (510)
    np.testing.assert_array_equal(r.pooled_mask(), [[True, True, True, False],
                                                    [True, False, False, False]])
    assert r.pooled_bin() == (2 + 0 + 1 + 480, pytest.approx(0.19 + 2.5 + 1.2 + 510.0), 4)
    assert not r.fail_pooled() and n_pooled == 4
    assert _terms_sum(r) == pytest.approx(stat, rel=1e-12)


def test_reported_terms_sum_to_the_statistic_of_a_run():
    """The pooling the result reports (``pooled_mask``, ``pooled_bin``, ``fail_pooled``) is the one
    the statistic used: the reported terms add up to it, and no pooled cell is listed alone."""
    sample, pdf = phong()
    r = chi2.chi2_test(sample, pdf, n_samples=N)
    pooled = r.pooled_mask()
    assert pooled.sum() > 10 and r.n_pooled == pooled.sum() + r.fail_pooled()
    assert np.max(r.contributions()[pooled]) > 0.0  # some pooled cells did receive samples
    assert _terms_sum(r) == pytest.approx(r.statistic, rel=1e-12)
    mu_e, phi_e = r.mu_edges, r.phi_edges
    pooled_labels = {
        f"[{mu_e[i]:+.3f},{mu_e[i + 1]:+.3f}) [{phi_e[j]:6.3f},{phi_e[j + 1]:6.3f})"
        for i, j in zip(*np.nonzero(pooled), strict=True)
    }
    rows = r.worst_cells(r.res_mu * r.res_phi).splitlines()[1:-1]
    assert not any(row[:31] in pooled_labels for row in rows)
    assert sum(row.startswith("pooled bin") for row in rows) == 1
    assert len(rows) == r.n_bins - (0 if r.fail_pooled() else 1)


# --------------------------------------------------------------------------------------------
# Monte Carlo p-values
# --------------------------------------------------------------------------------------------


def test_monte_carlo_p_value_matches_the_exact_binomial_tail():
    """Two bins (E = 5, 15 of n = 20): the statistic is ``(O1 - 5)^2 (1/5 + 1/15)``, so
    ``P(T >= T(O1 = 11)) = P(O1 >= 11)`` exactly; the simulated statistics that equal the observed
    one (a tie) count as exceedances."""
    be, n = np.array([5.0, 15.0]), 20
    t_obs = (11 - 5) ** 2 * (1 / 5 + 1 / 15)
    exact = stats.binom.sf(10, n, 0.25)  # 0.0039
    p, draws = chi2.monte_carlo_sf(t_obs, be, n, 200_000, seed=3)
    assert draws == 200_000
    assert abs(p - exact) < 4.0 * math.sqrt(exact / draws), (p, exact)
    assert chi2.monte_carlo_sf(t_obs, be, n, 20_000, seed=3) == chi2.monte_carlo_sf(
        t_obs, be, n, 20_000, seed=3)  # deterministic


def test_chi2_approximation_understates_the_far_tail_of_small_bins():
    """Why the Monte Carlo p-value exists: with ten bins of E = 5 the statistic exceeds the
    chi-square(10) quantile of 1e-4 about 7x as often (Poisson tails are heavier than normal
    ones), while the rule E >= 5 is met."""
    be = np.array([5.0] * 10 + [1e5 - 50.0])
    t = stats.chi2.isf(1e-4, be.size - 1)
    p, _ = chi2.monte_carlo_sf(t, be, 100_000, 200_000, seed=1)
    assert p > 3e-4, p


def test_inconclusive_p_value_is_replaced_by_the_monte_carlo_one():
    """A chi-square p-value within ``(threshold * MC_WINDOW, threshold]`` is replaced by the Monte
    Carlo one (``mc_draws`` draws); above the threshold, or with ``monte_carlo=False``, it stays."""
    r0 = chi2.chi2_test(cosine_sample, cosine_pdf, n_samples=N)
    assert r0.passed and r0.mc_draws == 0 and r0.p_value == r0.p_value_chi2
    alpha = min(0.99, 1.5 * r0.p_value)  # the chi-square p-value is now inconclusive
    r = chi2.chi2_test(cosine_sample, cosine_pdf, n_samples=N, alpha=alpha)
    assert r.mc_draws > 0 and r.p_value_chi2 == r0.p_value and r.statistic == r0.statistic
    assert r.passed == (r.p_value > r.threshold) and "Monte Carlo" in str(r)
    off = chi2.chi2_test(cosine_sample, cosine_pdf, n_samples=N, alpha=alpha, monte_carlo=False)
    assert off.mc_draws == 0 and off.p_value == r0.p_value and not off.passed


# --------------------------------------------------------------------------------------------
# Correct samplers pass
# --------------------------------------------------------------------------------------------


def test_cosine_sampler_passes():
    r = chi2.chi2_test(cosine_sample, cosine_pdf, n_samples=N)
    assert r.passed, str(r) + "\n" + r.worst_cells()
    assert (r.res_mu, r.res_phi) == (10, 20)
    assert r.n_fail == 0 and r.expected_fail_fraction < 1e-12
    assert r.observed.sum() == N
    np.testing.assert_allclose(r.expected.sum(), N, rtol=1e-12)
    assert r.expected[: r.res_mu // 2].max() == 0.0  # nothing expected below the horizon
    assert r.pdf_mismatch_fraction == 0.0


def test_uniform_sphere_passes():
    r = chi2.chi2_test(sphere_sample, sphere_pdf, n_samples=N)
    assert r.passed, str(r) + "\n" + r.worst_cells()
    assert r.dof == r.res_mu * r.res_phi - 1  # every cell is its own bin
    np.testing.assert_allclose(r.expected, N / r.expected.size, rtol=1e-12)


def test_tilted_phong_with_failures_passes():
    sample, pdf = phong()
    r = chi2.chi2_test(sample, pdf, n_samples=N)
    assert r.passed, str(r) + "\n" + r.worst_cells()
    assert r.n_fail > 100 and abs(r.fail_z) < 4.0
    # the expected failure probability agrees with an independent hemisphere quadrature of the
    # pdf (panels break the lobe's steep flank; the pdf is smooth above the horizon)
    rule = composite_gauss_legendre_hemisphere((0.3, 0.5, 0.7, 0.9), 24, 256)
    p_fail = 1.0 - float(integrate(pdf, rule))
    assert r.expected_fail_fraction == pytest.approx(p_fail, rel=1e-4)
    # ... and the observed failure fraction matches it within binomial noise
    assert abs(r.fail_fraction - p_fail) < 4.0 * math.sqrt(p_fail * (1.0 - p_fail) / N)
    assert r.pdf_max_rel_err < 1e-10


def test_lobe_choice_uniform_is_passed_to_a_two_argument_sampler():
    sample, pdf = phong()

    @jax.jit
    def mixture_sample(uc, u):  # 30 % cosine, 70 % tilted Phong, chosen by uc
        wi_c, _ = cosine_sample(u)
        wi_p, _ = sample(u)
        wi = jnp.where((uc < 0.3)[:, None], wi_c, wi_p)
        ok = wi[:, 2] > 0.0
        return wi, jnp.where(ok, mixture_pdf(jnp.where(ok[:, None], wi, 0.0)), 0.0)

    @jax.jit
    def mixture_pdf(wi):
        return 0.3 * cosine_pdf(wi) + 0.7 * pdf(wi)

    r = chi2.chi2_test(mixture_sample, mixture_pdf, n_samples=N)
    assert r.passed, str(r) + "\n" + r.worst_cells()
    assert r.n_fail > 0 and r.pdf_max_rel_err < 1e-10


# --------------------------------------------------------------------------------------------
# Negative controls: broken samplers fail
# --------------------------------------------------------------------------------------------


def test_pdf_scaled_by_1p1_fails():
    r = chi2.chi2_test(cosine_sample, cosine_pdf_scaled, n_samples=N)
    assert not r.passed
    assert r.p_value < r.threshold and r.statistic > 5.0 * _critical(r), str(r)
    np.testing.assert_allclose(r.expected.sum(), 1.1 * N, rtol=1e-12)
    assert r.expected_fail_fraction == 0.0  # clamped: the pdf integrates to 1.1
    assert r.pdf_mismatch_fraction == 1.0  # the sampler's own pdf disagrees everywhere


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_exponent_drift_21_vs_20_fails(seed):
    sample, pdf = phong(n_sample=EXPONENT + 1, n_pdf=EXPONENT)
    r = chi2.chi2_test(sample, pdf, n_samples=N, seed=seed)
    assert not r.passed
    # well clear of the rejection boundary, not a borderline fluke
    assert r.p_value < 1e-6 * r.threshold and r.statistic > 2.0 * _critical(r), str(r)


def test_exponent_drift_about_the_normal_fails_on_a_finer_mu_grid():
    # A lobe about the normal falls in one 0.2-wide mu band of the 10 x 20 grid, which hides its
    # width. It is rotationally symmetric, so a fine grid in mu and a coarse one in phi resolve the
    # width without diluting the counts.
    sample, pdf = phong(n_sample=EXPONENT + 1, n_pdf=EXPONENT, tilt=0.0)
    r = chi2.chi2_test(sample, pdf, n_samples=N, res_mu=40, res_phi=4)
    assert not r.passed and r.statistic > 2.0 * _critical(r), str(r)


def test_phi_restricted_to_0_1p9pi_fails():
    sample, pdf = phong(phi_max=1.9 * math.pi)
    r = chi2.chi2_test(sample, pdf, n_samples=N)
    assert not r.passed and r.statistic > 5.0 * _critical(r), str(r)
    table = r.worst_cells(3)
    assert len(table.splitlines()) == 3 + 2  # header, 3 cells, failures


def test_cosine_sampler_phi_restricted_fails():
    @jax.jit
    def sample(u):
        return cosine_sample(jnp.stack([u[:, 0], 0.95 * u[:, 1]], axis=-1))

    r = chi2.chi2_test(sample, cosine_pdf, n_samples=N)
    assert not r.passed and r.statistic > 5.0 * _critical(r), str(r)
    assert r.observed[:, -1].sum() == 0  # the last azimuth column [1.9 pi, 2 pi) stays empty


def test_samples_where_the_pdf_is_zero_fail():
    @jax.jit
    def sample(u):  # mirrors 1 % of the cosine samples below the horizon, pdf still > 0
        wi, p = cosine_sample(u)
        flip = (u[:, 0] < 0.01)[:, None]
        return jnp.where(flip, wi * jnp.array([1.0, 1.0, -1.0]), wi), p

    r = chi2.chi2_test(sample, cosine_pdf, n_samples=N)
    assert not r.passed
    assert r.n_zero_cell_samples > 0 and r.statistic == math.inf and r.p_value == 0.0
    assert r.to_dict()["statistic"] is None


def test_wrong_failure_count_fails():
    @jax.jit
    def sample(uc, u):  # 2 % of samples fail at random, though the pdf integrates to 1
        wi, p = cosine_sample(u)
        return wi, jnp.where(uc < 0.02, 0.0, p)

    r = chi2.chi2_test(sample, cosine_pdf, n_samples=N)
    assert not r.passed
    assert r.fail_fraction == pytest.approx(0.02, abs=0.002) and abs(r.fail_z) > r.fail_z_threshold


def test_invalid_samples_fail():
    @jax.jit
    def sample(u):
        wi, p = cosine_sample(u)
        return wi, jnp.where(u[:, 1] < 1e-3, jnp.nan, p)

    r = chi2.chi2_test(sample, cosine_pdf, n_samples=N)
    assert not r.passed and r.n_invalid > 0
    assert any("invalid" in s for s in r.reasons)


def test_negative_pdf_fn_fails():
    r = chi2.chi2_test(cosine_sample, lambda wi: cosine_pdf(wi) - 0.01, n_samples=20_000)
    assert not r.passed and any("negative" in s for s in r.reasons)


# --------------------------------------------------------------------------------------------
# Determinism, reporting, BRDF wrapper, float32
# --------------------------------------------------------------------------------------------


def test_determinism_and_chunk_independence():
    sample, pdf = phong()
    a = chi2.chi2_test(sample, pdf, n_samples=20_000, seed=7)
    b = chi2.chi2_test(sample, pdf, n_samples=20_000, seed=7)
    assert a.statistic == b.statistic and a.p_value == b.p_value
    np.testing.assert_array_equal(a.observed, b.observed)
    c = chi2.chi2_test(sample, pdf, n_samples=20_000, seed=7, chunk_size=3_000)
    np.testing.assert_array_equal(a.observed, c.observed)
    assert a.n_fail == c.n_fail
    d = chi2.chi2_test(sample, pdf, n_samples=20_000, seed=8)
    assert not np.array_equal(a.observed, d.observed)


def test_report_formats():
    r = chi2.chi2_test(sphere_sample, sphere_pdf, n_samples=20_000, test_count=10)
    assert r.threshold == pytest.approx(chi2.sidak_threshold(0.01, 10))
    assert str(r).startswith("chi2 test PASSED")
    d = r.to_dict()
    text = json.dumps(d, allow_nan=False)
    assert json.loads(text)["dof"] == r.dof
    assert np.array_equal(np.asarray(d["observed"]), r.observed)
    assert d["res_mu"] == r.res_mu and isinstance(d["passed"], bool)


class _MixtureBRDF:
    """Test double with the model API: ``sample(wo, uc, u) -> obj(.wi, .pdf)``, ``pdf(wi, wo)``.

    Lambertian (weight ``p_diffuse``) plus a Phong lobe (exponent 20) about the mirror direction
    of ``wo``; ``sample_p_diffuse`` is the lobe-selection probability actually used by ``sample``.
    """

    def __init__(self, p_diffuse=0.4, sample_p_diffuse=None):
        self.p = p_diffuse
        self.ps = p_diffuse if sample_p_diffuse is None else sample_p_diffuse

    class Sample:
        def __init__(self, wi, pdf):
            self.wi, self.pdf = wi, pdf

    def _lobe(self, wo):
        return wo * jnp.array([-1.0, -1.0, 1.0])

    def pdf(self, wi, wo):
        c = jnp.clip(jnp.sum(wi * self._lobe(wo), axis=-1), 0.0, None)
        phong_pdf = 21.0 / (2.0 * jnp.pi) * c**20
        total = self.p * wi[..., 2] / jnp.pi + (1.0 - self.p) * phong_pdf
        return jnp.where(wi[..., 2] > 0.0, total, 0.0)

    def sample(self, wo, uc, u):
        r = self._lobe(wo)
        t = jnp.cross(jnp.array([0.0, 0.0, 1.0]), r)
        t = t / jnp.linalg.norm(t, axis=-1, keepdims=True)
        b = jnp.cross(r, t)
        loc_p = _from_local(u[:, 0] ** (1.0 / 21.0), 2.0 * jnp.pi * u[:, 1])
        wi_p = loc_p[:, :1] * t + loc_p[:, 1:2] * b + loc_p[:, 2:] * r
        wi_d = _from_local(jnp.sqrt(u[:, 0]), 2.0 * jnp.pi * u[:, 1])
        wi = jnp.where((uc < self.ps)[:, None], wi_d, wi_p)
        ok = wi[:, 2] > 0.0
        return self.Sample(wi, jnp.where(ok, self.pdf(jnp.where(ok[:, None], wi, 0.0), wo), 0.0))


WO = np.array([math.sin(math.radians(50.0)), 0.0, math.cos(math.radians(50.0))])


def test_brdf_wrapper_passes_for_a_consistent_model():
    r = chi2.chi2_test_brdf(_MixtureBRDF(), WO, n_samples=N)
    assert r.passed, str(r) + "\n" + r.worst_cells()
    assert r.n_fail > 0 and r.pdf_max_rel_err < 1e-10


def test_brdf_wrapper_fails_for_a_wrong_lobe_selection():
    r = chi2.chi2_test_brdf(_MixtureBRDF(0.4, sample_p_diffuse=0.45), WO, n_samples=N)
    assert not r.passed and r.statistic > 2.0 * _critical(r), str(r)


def test_float32_uniforms_and_directions():
    r = chi2.chi2_test(cosine_sample, cosine_pdf, n_samples=20_000, dtype=jnp.float32)
    assert r.passed, str(r)
    assert r.pdf_max_rel_err < 1e-5


# --------------------------------------------------------------------------------------------
# Lobe-aligned grid for narrow lobes
# --------------------------------------------------------------------------------------------


def _view(cos_o, azimuth=0.7):
    s = math.sqrt(1.0 - cos_o * cos_o)
    return np.array([s * math.cos(azimuth), s * math.sin(azimuth), cos_o])


def test_lobe_grid_edges_have_equal_lobe_mass():
    frame, edges = chi2.lobe_grid(np.array([0.3, -0.2, 0.9]), 1e4, 20)
    np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(frame[2], np.array([0.3, -0.2, 0.9]) / np.linalg.norm([.3, .2, .9]))
    assert edges[0] == -1 and edges[-1] == 1 and np.all(np.diff(edges) > 0)
    mass = np.diff(np.clip(edges, 0, 1) ** (1e4 + 1))
    np.testing.assert_allclose(mass[-14:], 1 / 15, rtol=1e-9)  # 14 rings of mass 1/15
    np.testing.assert_allclose(mass[-18:-14], [1e-6, 1e-4 - 1e-6, 1e-2 - 1e-4, 1 / 15 - 1e-2],
                               rtol=1e-9)  # the tail cells
    with pytest.raises(ValueError, match="res_mu"):
        chi2.lobe_grid(np.array([0, 0, 1.0]), 10.0, 5)


def test_narrow_lobe_uses_lobe_grid_and_rejects_a_drift():
    """At n = 1e4 the lobe (~0.6 deg) fills one or two cells of the sphere grid, so a sampler whose
    lobe is 5% too narrow goes unseen there; the lobe-aligned grid sees it."""
    from brdf_fit.models.phong_normalized import EnergyNormalizedPhong
    from brdf_fit.verify.checks import DriftingSampler

    model = EnergyNormalizedPhong(rho_s=0.8, exponent=jnp.asarray(1e4))
    wo = jnp.asarray(_view(0.3))
    good = chi2.chi2_test_brdf(model, wo, n_samples=N, test_count=3)
    assert good.passed, str(good)
    assert good.frame is not None and good.dof > 100  # the automatic lobe grid was used
    sphere = chi2.chi2_test_brdf(model, wo, lobe=None, n_samples=N, test_count=3)
    assert sphere.dof <= 3  # why the lobe grid exists: the sphere grid has no power here
    bad = DriftingSampler(model, drift=0.05)  # cos = u0^(1.05/(n+1)): a 5% narrower lobe
    axis = np.asarray(wo) * np.array([-1.0, -1.0, 1.0])
    frame, edges = chi2.lobe_grid(axis, 1e4, 20)
    r = chi2.chi2_test_brdf(bad, wo, n_samples=N, test_count=3, frame=frame, mu_edges=edges)
    assert not r.passed and r.p_value < 1e-6, str(r)
    assert "mu range" in r.worst_cells() and json.dumps(r.to_dict())
