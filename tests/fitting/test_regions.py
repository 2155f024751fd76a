"""brdf_fit.fitting.regions: the regions against the half and difference angles computed
independently (the MERL reference code's conversion, brdf_fit.io.merl.half_diff_angles), and
the summary against closed forms: a model that is the data to rounding, and a Lambertian
model against data 10% brighter at grazing only (every log ratio there known exactly)."""

import numpy as np

from brdf_fit import registry
from brdf_fit.fitting.problem import RELATIVE_FLOOR
from brdf_fit.fitting.regions import (
    GRAZING_DEG,
    PEAK_DEG,
    REGIONS,
    RETRO_DEG,
    region_index,
    residuals_by_region,
)
from brdf_fit.io.merl import half_diff_angles
from tests._helpers import random_dirs


def _pairs(n=4000, seed=3):
    rng = np.random.default_rng(seed)
    wi, wo = random_dirs(rng, n), random_dirs(rng, n)
    # the named cases: normal incidence and view (peak), retro at 40 deg, grazing light
    s40, c40, s80, c80 = np.sin(0.698), np.cos(0.698), np.sin(1.396), np.cos(1.396)
    wi[:3] = [[0, 0, 1], [s40, 0, c40], [s80, 0, c80]]
    wo[:3] = [[0, 0, 1], [s40, 0, c40], [0, 0, 1]]
    return wi, wo


def test_regions_follow_the_half_and_difference_angles():
    wi, wo = _pairs()
    th, td, _ = half_diff_angles(wi, wo)
    th, td = np.degrees(th), np.degrees(td)
    zi, zo = np.degrees(np.arccos(wi[:, 2])), np.degrees(np.arccos(wo[:, 2]))
    want = np.select([(zi >= GRAZING_DEG) | (zo >= GRAZING_DEG), th < PEAK_DEG, td < RETRO_DEG],
                     [0, 1, 2], 3)
    # pairs within 1e-9 deg of a boundary could fall either way in rounding: none here
    near = np.minimum.reduce([abs(zi - GRAZING_DEG), abs(zo - GRAZING_DEG), abs(th - PEAK_DEG),
                              abs(td - RETRO_DEG)])
    assert near.min() > 1e-9
    got = region_index(wi, wo)
    np.testing.assert_array_equal(got, want)
    assert [REGIONS[k] for k in got[:3]] == ["specular peak", "retro-reflection", "grazing"]
    assert all((got == k).sum() > 20 for k in range(4))  # every region drawn


def test_summary_of_a_model_that_is_the_data():
    wi, wo = _pairs()
    m = registry.get("ggx").build(alpha=0.3, f0=0.5)
    f = np.asarray(m.eval(wi, wo), float)
    rows = residuals_by_region(m, wi, wo, f)
    assert [r["region"] for r in rows] == list(REGIONS)
    assert sum(r["samples"] for r in rows) == len(wi)
    np.testing.assert_allclose(sum(r["share"] for r in rows), 1.0, rtol=1e-15)
    for r in rows:  # the same program as the data's, in blocks: rounding only
        assert r["rms_log_ratio"] < 1e-13 and abs(r["mean_factor"]) < 1e-13, r


def test_summary_finds_a_misfit_at_grazing_only():
    """A broken model (data 10% brighter at grazing than the Lambertian model) shows in the
    grazing row alone, by the exact factor; the other rows are exact."""
    wi, wo = _pairs()
    rho = np.array([0.2, 0.5, 0.8])
    m = registry.get("lambert").build(rho=rho)
    grazing = region_index(wi, wo) == REGIONS.index("grazing")
    f = np.broadcast_to(rho / np.pi, (len(wi), 3)) * np.where(grazing, 1.1, 1.0)[:, None]
    rows = {r["region"]: r for r in residuals_by_region(m, wi, wo, f)}
    floor = RELATIVE_FLOOR * f.max()
    exact = np.log((rho / np.pi + floor) / (1.1 * rho / np.pi + floor))
    np.testing.assert_allclose(rows["grazing"]["rms_log_ratio"], np.sqrt(np.mean(exact**2)),
                               rtol=1e-12)
    np.testing.assert_allclose(rows["grazing"]["mean_factor"], np.expm1(np.mean(exact)),
                               rtol=1e-12)
    assert rows["grazing"]["samples"] == grazing.sum()
    for name in REGIONS[1:]:
        assert rows[name]["rms_log_ratio"] < 1e-14, rows[name]
