"""The correlation matrix of a fit's estimates (issues 40 and 44): ``FitResult.correlation``
(the covariance the standard errors come from, scaled to unit diagonal), in the JSON, and the
strongly correlated pairs the command names (a conductor's eta and k where the data fix only
the reflectance they give)."""

import jax
import jax.numpy as jnp
import numpy as np
from _helpers import random_dirs

from brdf_fit import registry
from brdf_fit.data import GonioData
from brdf_fit.fitting.single import STRONG_CORRELATION, correlation, fit

N = 400


def _data(name, truth, max_deg, seed, noise=0.02):
    rng = np.random.default_rng(seed)
    lo = np.cos(np.radians(max_deg))  # zeniths up to max_deg
    wi, wo = random_dirs(rng, N, lo), random_dirs(rng, N, lo)
    m = registry.get(name).build(**{k: np.asarray(v) for k, v in truth.items()})
    v = np.asarray(m.eval(wi, wo)) * np.exp(noise * rng.standard_normal((N, 3)))
    return GonioData(wi, wo, v, channels=("R", "G", "B"))


def test_correlation_of_a_covariance():
    cov = np.array([[4.0, 1.0, 0.0], [1.0, 1.0, 0.5], [0.0, 0.5, 9.0]])
    c = correlation(cov, np.zeros(3, int))
    np.testing.assert_allclose(c, [[1, 0.5, 0], [0.5, 1, 0.5 / 3], [0, 0.5 / 3, 1]], rtol=1e-15)
    # an entry whose standard error is undefined (at bound, not identifiable): NaN row/column
    c = correlation(cov, np.array([0, 1, 0]))
    assert np.isnan(c[1]).all() and np.isnan(c[:, 1]).all() and c[0, 2] == 0 and c[0, 0] == 1
    assert np.isnan(correlation(None, np.zeros(2, int))).all()


def test_a_fit_reports_the_correlation_of_its_standard_errors():
    """An independent reading: the HC3 sandwich covariance (the estimator without sigma,
    fitting.solvers.SANDWICH; MacKinnon and White 1985) from a central-difference Jacobian of the
    log residuals ``log1p(f cos_i) - log1p(y cos_i)`` in the physical parameters, formed here
    with NumPy."""
    truth = {"alpha": 0.23, "f0": [0.9, 0.6, 0.3]}
    d = _data("ggx", truth, 80.0, seed=1)
    r = fit(d, "ggx")
    assert r.converged
    assert r.correlation_labels == ("alpha", "f0[R]", "f0[G]", "f0[B]")
    x = np.concatenate([np.atleast_1d(r.params["alpha"]), r.params["f0"]])
    cos = d.wi[:, 2:3]
    entry = registry.get("ggx")
    model_at = jax.jit(lambda a, f0: entry.build(alpha=a, f0=f0).eval(d.wi, d.wo))

    def residuals(x):
        f = np.asarray(model_at(jnp.asarray(x[0]), jnp.asarray(x[1:])))
        return (np.log1p(f * cos) - np.log1p(d.value * cos)).reshape(-1)

    h = 1e-6
    J = np.stack([(residuals(x + h * e) - residuals(x - h * e)) / (2 * h)
                  for e in np.eye(x.size)], -1)
    res = residuals(x)
    bread = np.linalg.inv(J.T @ J)
    leverage = np.array([row @ bread @ row for row in J])
    cov = bread @ (J.T @ (J * (res / (1 - leverage))[:, None] ** 2)) @ bread
    s = np.sqrt(np.diag(cov))
    np.testing.assert_allclose(s, [r.stderr["alpha"], *r.stderr["f0"]], rtol=1e-5)
    np.testing.assert_allclose(r.correlation, cov / np.outer(s, s), atol=1e-6)
    # alpha and f0 are told apart by these data: no pair is named
    assert r.strongly_correlated() == []
    doc = r.to_dict()["correlation"]
    assert doc["labels"] == list(r.correlation_labels)
    np.testing.assert_allclose(doc["matrix"], r.correlation, rtol=0, atol=0)


def test_a_conductor_seen_near_the_normal_names_eta_and_k():
    """Directions within 25 degrees of the normal see a conductor's Fresnel factor at nearly
    one angle: the data fix the reflectance each (eta, k) pair gives, not the pair. The
    correlated pairs named are those, channel by channel, and the control (directions to 85
    degrees, alpha and F0 of GGX) names none."""
    truth = {"alpha": 0.2, "eta": [0.27, 0.68, 1.2], "k": [3.6, 2.6, 2.3]}
    r = fit(_data("ggx-conductor", truth, 25.0, seed=0, noise=0.01), "ggx-conductor",
            max_steps=64)
    pairs = r.strongly_correlated()
    assert len(pairs) >= 2
    for a, b, rho in pairs:
        assert {a[:-3], b[:-3]} == {"eta", "k"} and a[-3:] == b[-3:], pairs  # same channel
        assert abs(rho) >= STRONG_CORRELATION
    assert r.strongly_correlated(threshold=1.01) == []
