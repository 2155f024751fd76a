"""Tests of brdf_fit.core.spectra: n, k tables, spectral Fresnel, colour and effective RGB n, k."""

from __future__ import annotations

import colour
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from brdf_fit.core import spectra
from brdf_fit.core.fresnel import conductor

EXPECTED_MATERIALS = {"Ag", "Al", "Au", "Cr", "Cu", "Fe", "Ni", "Ti"}
ANGLES_DEG = np.array([0.0, 20.0, 45.0, 60.0, 75.0, 85.0, 89.0, 90.0])


def test_materials_are_the_shipped_tables():
    assert set(spectra.materials()) == EXPECTED_MATERIALS


@pytest.mark.parametrize("name", sorted(EXPECTED_MATERIALS))
def test_tables_load_physically(name):
    wl, n, k = spectra.load_nk(name)
    assert wl.dtype == n.dtype == k.dtype == np.float64
    assert wl.shape == n.shape == k.shape and wl.size > 10
    assert np.all(np.diff(wl) > 0)
    assert np.all(n > 0) and np.all(k > 0)
    # the default visible grid is covered by every table
    grid = spectra.default_wavelengths()
    assert wl[0] <= grid[0] and wl[-1] >= grid[-1]
    src = spectra.source(name)
    assert "source:" in src and "doi" in src
    # returned arrays are copies: mutating them does not corrupt later loads
    n[:] = -1.0
    assert np.all(spectra.load_nk(name)[1] > 0)


def test_default_wavelengths():
    wl = spectra.default_wavelengths()
    assert wl.shape == (41,)
    np.testing.assert_allclose(wl, np.arange(380, 781, 10))


def test_nk_at_interpolates_linearly():
    wl, n, k = spectra.load_nk("Cu")
    inside = (wl > 350) & (wl < 900)
    n_at, k_at = spectra.nk_at("Cu", wl[inside])
    np.testing.assert_allclose(n_at, n[inside], rtol=1e-12)
    np.testing.assert_allclose(k_at, k[inside], rtol=1e-12)
    i = np.flatnonzero(inside)[0]
    mid = 0.25 * wl[i] + 0.75 * wl[i + 1]
    n_mid, k_mid = spectra.nk_at("Cu", mid)
    np.testing.assert_allclose(n_mid, 0.25 * n[i] + 0.75 * n[i + 1], rtol=1e-12)
    np.testing.assert_allclose(k_mid, 0.25 * k[i] + 0.75 * k[i + 1], rtol=1e-12)


@pytest.mark.parametrize(
    "call",
    [
        lambda: spectra.load_nk("Unobtainium"),
        lambda: spectra.source("Unobtainium"),
        lambda: spectra.nk_at("Unobtainium", [500.0]),
        lambda: spectra.rgb_nk("Unobtainium"),
        lambda: spectra.conductor_fresnel("Unobtainium"),
    ],
)
def test_unknown_material_lists_valid_names(call):
    with pytest.raises(ValueError, match="Unobtainium") as info:
        call()
    for name in EXPECTED_MATERIALS:
        assert name in str(info.value)


@pytest.mark.parametrize("bad", [[500.0, 3000.0], [100.0], [np.nan]])
def test_out_of_range_wavelength_raises(bad):
    wl = spectra.load_nk("Au")[0]
    with pytest.raises(ValueError, match="nm") as info:
        spectra.nk_at("Au", bad)
    assert f"{wl[0]:g}" in str(info.value) and f"{wl[-1]:g}" in str(info.value)
    with pytest.raises(ValueError):
        spectra.spectral_reflectance("Au", 1.0, bad)


def test_white_and_grey_spectra():
    wl = spectra.default_wavelengths()
    np.testing.assert_allclose(spectra.spectrum_to_rgb(np.ones_like(wl), wl), 1.0, atol=1e-3)
    np.testing.assert_allclose(spectra.spectrum_to_rgb(np.full_like(wl, 0.5), wl), 0.5, atol=1e-3)
    # another (irregular) grid, with leading batch axes
    wl2 = np.concatenate([np.arange(370.0, 600.0, 5.0), np.arange(600.0, 800.0, 20.0)])
    levels = np.array([[0.0, 0.25, 1.0], [0.5, 0.75, 0.1]])
    rgb = spectra.spectrum_to_rgb(levels[..., None] * np.ones_like(wl2), wl2)
    assert rgb.shape == (2, 3, 3)
    np.testing.assert_allclose(rgb, np.repeat(levels[..., None], 3, axis=-1), atol=1e-3)


def test_spectrum_to_rgb_matches_colour_science_directly():
    """A smooth reddish spectrum on colour-science's own 1 nm grid, converted by colour-science's
    SpectralDistribution path, agrees with spectrum_to_rgb (up to the <= 2e-4 white balance)."""
    shape = colour.SpectralShape(360, 780, 1)
    wl = shape.wavelengths
    refl = 0.2 + 0.6 / (1.0 + np.exp(-(wl - 580.0) / 20.0))
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().trim(shape)
    d65 = colour.SDS_ILLUMINANTS["D65"].copy().align(shape)
    sd = colour.SpectralDistribution(refl, wl)
    with colour.utilities.domain_range_scale("1"):
        xyz = colour.sd_to_XYZ(sd, cmfs, d65)
        expected = colour.XYZ_to_RGB(xyz, "sRGB")
    got = spectra.spectrum_to_rgb(refl, wl)
    np.testing.assert_allclose(got, expected, atol=5e-4)
    assert got[0] > got[1] > got[2]


def test_spectral_reflectance_normal_incidence_and_shapes():
    wl = spectra.default_wavelengths()
    for name in spectra.materials():
        n, k = spectra.nk_at(name, wl)
        f0 = ((n - 1.0) ** 2 + k**2) / ((n + 1.0) ** 2 + k**2)
        got = np.asarray(spectra.spectral_reflectance(name, 1.0))
        np.testing.assert_allclose(got, f0, rtol=1e-10, atol=1e-12)
    cos = jnp.asarray(np.cos(np.deg2rad(ANGLES_DEG)).reshape(2, 4))
    r = spectra.spectral_reflectance("Au", cos)
    assert isinstance(r, jax.Array) and r.shape == (2, 4, wl.size)
    assert np.all(np.asarray(r) <= 1.0) and np.all(np.asarray(r) > 0.0)
    np.testing.assert_allclose(np.asarray(r)[1, 3], 1.0, atol=1e-12)  # 90 degrees: mirror
    r5 = spectra.spectral_reflectance("Ag", 0.3, [450.0, 550.0, 650.0])
    assert r5.shape == (3,)


def test_spectral_reflectance_is_differentiable_in_cos():
    g = jax.grad(lambda c: jnp.sum(spectra.spectral_reflectance("Cu", c)))(0.5)
    assert np.isfinite(float(g)) and float(g) < 0.0  # reflectance rises towards grazing


def test_metal_colours_are_physical():
    au = spectra.reflectance_rgb("Au")
    assert au.shape == (3,)
    assert au[0] > au[1] > au[2]
    cu = spectra.reflectance_rgb("Cu")
    assert cu[0] > cu[1] and cu[0] > cu[2]
    ag = spectra.reflectance_rgb("Ag")
    assert np.all(ag > 0.9) and np.ptp(ag) < 0.03
    # every metal goes to white at grazing incidence
    grazing = spectra.reflectance_rgb("Ni", np.array([0.0, 1e-9]))
    np.testing.assert_allclose(grazing, 1.0, atol=1e-6)


@pytest.mark.parametrize("name", sorted(EXPECTED_MATERIALS))
def test_rgb_nk_reproduces_rgb_reflectance(name):
    eta, k = spectra.rgb_nk(name)
    err = spectra.rgb_nk_fit_error(name)
    assert eta.shape == k.shape == err.shape == (3,)
    assert np.all(np.isfinite(eta)) and np.all(eta > 0) and np.all(k > 0)
    cos = np.cos(np.deg2rad(ANGLES_DEG))
    target = spectra.reflectance_rgb(name, cos)
    fitted = np.asarray(conductor(jnp.asarray(cos)[:, None], jnp.asarray(eta), jnp.asarray(k)))
    assert np.all(np.abs(fitted - target) <= err + 1e-9)
    # A conductor cannot reflect more than 1: a channel out of the sRGB gamut (above 1) is
    # clipped to R_CLIP and keeps an error of its excess over R_CLIP; every other channel must
    # fit tightly.
    dense = spectra.reflectance_rgb(name, np.linspace(0.0, 1.0, 101))
    out = dense.max(axis=0) > 1.0
    excess = np.where(out, dense.max(axis=0) - spectra.R_CLIP, 0.0)
    assert np.all(err < 5e-3 + excess)
    assert np.all(err[~out] < 5e-3)


def test_gold_red_is_out_of_gamut_and_clipped_to_a_real_conductor():
    """Gold's linear-sRGB red exceeds 1 (1.037 at normal incidence): it is clipped to R_CLIP
    before the fit, so the red channel is a real conductor inside the box (issue 16: it used to
    end at the box corner eta = 1e-3, k = 100, F = 1 - 5e-7 at every angle)."""
    red = spectra.reflectance_rgb("Au")[0]
    assert red > 1.0
    eta, k = spectra.rgb_nk("Au")
    assert 1e-3 < eta[0] < 1.0 and 1.0 < k[0] < 100.0  # interior, not the box
    f_red = float(conductor(1.0, jnp.asarray(eta[0]), jnp.asarray(k[0])))
    assert abs(f_red - spectra.R_CLIP) < 2e-3
    np.testing.assert_allclose(spectra.rgb_nk_fit_error("Au")[0], red - f_red, rtol=1e-3)


def test_conductor_fresnel_from_material():
    rgb = spectra.conductor_fresnel("Au", "rgb")
    assert rgb.eta.shape == rgb.k.shape == (3,)
    np.testing.assert_allclose(rgb.eta, spectra.rgb_nk("Au")[0])
    f_rgb = np.asarray(rgb(0.5))
    np.testing.assert_allclose(f_rgb, spectra.reflectance_rgb("Au", 0.5), atol=0.05)
    spec = spectra.conductor_fresnel("Au", "spectral")
    assert spec.eta.shape == spec.k.shape == (41,)
    np.testing.assert_allclose(
        np.asarray(spec(0.7)), np.asarray(spectra.spectral_reflectance("Au", 0.7)), rtol=1e-12
    )
    with pytest.raises(ValueError):
        spectra.conductor_fresnel("Au", "hyperspectral")
