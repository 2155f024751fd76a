"""The residual picture (brdf_fit.plot.residuals, ``brdf-fit plot --data``'s second file) shows
where the misfit is: under each model's panel, one bar per region of the geometry whose length
is that region's rms log ratio as ``fit`` reports it (brdf_fit.fitting.regions), the largest in
red, each labelled with the model's mean reading there (issue 40)."""

import matplotlib
import numpy as np

from brdf_fit import registry
from brdf_fit.data import GonioData
from brdf_fit.fitting.regions import REGIONS, residuals_by_region
from brdf_fit.plot import residuals

matplotlib.use("Agg")


def _data():
    rng = np.random.default_rng(40)
    n = 400
    mu_i, mu_o = rng.uniform(0.05, 1.0, n), rng.uniform(0.05, 1.0, n)
    phi = rng.uniform(0.0, 2 * np.pi, n)
    wi = np.stack([np.sqrt(1 - mu_i**2), np.zeros(n), mu_i], -1)
    wo = np.stack([np.sqrt(1 - mu_o**2) * np.cos(phi), np.sqrt(1 - mu_o**2) * np.sin(phi),
                   mu_o], -1)
    truth = registry.get("ggx").build(alpha=0.3, f0=np.array([0.9, 0.6, 0.3]))
    v = np.asarray(truth.eval(wi, wo))
    return GonioData(wi=wi, wo=wo, value=v, channels=("R", "G", "B")), truth


def test_region_bars_are_the_fit_summary():
    data, truth = _data()
    other = registry.get("lambert").build(rho=np.array([0.3, 0.2, 0.1]))
    fig = residuals(data, [("truth", truth), ("lambert", other)])
    bars = fig.axes[2:]  # the scatter panels first, then one bar panel per model
    assert len(bars) == 2
    for ax, model in zip(bars, (truth, other), strict=True):
        want = residuals_by_region(model, data.wi, data.wo, data.value)
        widths = [p.get_width() for p in ax.patches]
        got = {r["region"]: r["rms_log_ratio"] for r in want if r["samples"]}
        np.testing.assert_allclose(widths, list(got.values()), rtol=1e-12)
        red = [p for p in ax.patches if p.get_facecolor()[:3] == matplotlib.colors.to_rgb(
            "tab:red")]
        assert len(red) == 1 and red[0].get_width() == max(widths)
        labels = [t.get_text() for t in ax.texts]
        assert len(labels) == len(REGIONS)
    # the model that made the data misses by rounding only; lambert misses by far more
    assert max(p.get_width() for p in bars[0].patches) < 1e-6
    assert max(p.get_width() for p in bars[1].patches) > 0.5
