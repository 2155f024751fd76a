"""Model-mismatch conversion (brdf_fit.convert.phong_to_ggx, ``brdf-fit convert phong-to-ggx``):
the fits converge and beat the closed form in their own metric, the large-exponent GGX widths
agree with Walter's closed form within the measured factor, the geometry is the stated one, the
JSON table interpolates, and user errors are one line with exit status 2."""

import json
import math

import jax.numpy as jnp
import numpy as np
import pytest

from brdf_fit import registry
from brdf_fit.cli import main
from brdf_fit.convert.phong_to_ggx import (
    PEAK_F0,
    REPRESENTS_TOL,
    ConversionError,
    alpha_from_table,
    geometry,
    phong_to_ggx,
    source_scale,
)

#: alpha_fit / alpha_closed must lie in (1/FACTOR, FACTOR) for Blinn-Phong n >= 100.
#:
#: Measured (default geometry, log metric, float64; `brdf-fit convert phong-to-ggx --source
#: blinn-phong --exponents 100 300 1000 3000 10000`): ratio 1.717, 1.378, 0.981, 0.768, 0.609
#: (and 1.421, 0.966 for modified Phong n = 100, 1000). The two cannot be equal, and the ratio
#: has no large-n limit, for three measured reasons: (1) at equal peak, GGX is narrower at half
#: maximum (HWHM tan(theta_h) = 0.644 alpha against 0.833 alpha for cos^n ~ exp(-tan^2/alpha^2))
#: but far heavier in the tails (alpha^2/tan^4 against exp(-n theta^2/2)); (2) the log metric
#: ln(1 + f cos) is not scale-free: the peak grows ~ n, so at large n the residual is ~relative
#: and the deep tails (down to 1e-4 of the peak in the lobe grid) pull alpha down; the
#: blinn-phong-microfacet control, which differs from GGX in D only, drifts the same way (0.996,
#: 0.829, 0.659 at n = 100, 1000, 10000, measured by a profile scan); (3) the Blinn-Phong BRDF has
#: no F G/(4 cos_i cos_o): at theta_i = 75 deg GGX is ~1/(4 cos^2 75 deg) = 3.7 times brighter
#: relative to normal view, which widens the fit at moderate n (normal incidence alone gives
#: 1.14 at n = 100). A factor of 2 bounds the measured 0.61..1.72 with ~15% margin on each side.
FACTOR = 2.0


@pytest.fixture(scope="module")
def blinn():
    return phong_to_ggx("blinn-phong", exponents=[100.0, 1000.0])


def test_fits_converge_and_beat_the_closed_form(blinn):
    assert blinn.source == "blinn-phong" and blinn.metric == "log"
    for r in blinn.rows:
        assert r.converged and r.steps > 0
        # the fit starts at the closed form: it may only lower the metric's rms
        assert r.residual_rms < r.closed_rms
        assert math.isfinite(r.max_rel_err) and r.max_rel_err > 0
        assert 0.0 < r.f0_fit < 1.0


def test_large_exponent_alpha_within_measured_factor_of_walter(blinn):
    for r in blinn.rows:
        assert r.alpha_closed == pytest.approx(math.sqrt(2.0 / (r.exponent + 2.0)), rel=1e-12)
        assert 1.0 / FACTOR < r.ratio < FACTOR, r.to_dict()
    # measured values (see FACTOR): the fit is wider than the peak match at n = 100, about equal
    # at n = 1000
    assert blinn.rows[0].ratio > 1.2
    assert abs(blinn.rows[1].ratio - 1.0) < 0.1


@pytest.mark.parametrize("source", ["modified-phong", "blinn-phong", "blinn-phong-approx",
                                    "blinn-phong-microfacet"])
@pytest.mark.parametrize("n", [3.0, 100.0])
def test_source_scale_matches_the_ggx_peak(source, n):
    """At wi = wo = normal, GGX at the closed-form alpha and f0 = PEAK_F0 equals the scaled
    source exactly (D(n) = 1/(pi alpha^2), G = 1, F = f0, 1/(4 cos cos) = 1/4)."""
    from brdf_fit.convert.phong_to_ggx import _closed_alpha

    z = jnp.asarray([[0.0, 0.0, 1.0]])
    entry = registry.get(source)
    params = {"f0" if "f0" in entry.param_names else "rho_s": source_scale(source, n),
              "exponent": n}
    if "rho_d" in entry.param_names:
        params["rho_d"] = 0.0
    f = float(np.ravel(entry.build(**params).eval(z, z))[0])
    m = float(np.ravel(registry.get("ggx").build(alpha=_closed_alpha(source, n),
                                                 f0=PEAK_F0).eval(z, z))[0])
    assert m == pytest.approx(f, rel=1e-12)


def test_geometry_is_the_stated_one():
    wi, wo = geometry(0.1, max_zenith_deg=70.0)
    cz = math.cos(math.radians(70.0))
    assert (wi[:, 2] >= cz).all() and (wo[:, 2] >= cz).all()
    np.testing.assert_allclose(np.linalg.norm(wo, axis=-1), 1.0, rtol=1e-12)
    off = np.abs(wo[:, 1]) > 1e-3  # off the plane of incidence (phi_i = 0)
    assert off.sum() > 100 and (~off).sum() > 20
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    assert (np.arccos(np.clip(h[:, 2], -1, 1)) < 0.1 * 0.5).sum() > 50  # the lobe core


def test_cli_convert_json_is_a_lookup_table(capsys):
    # exit status 1: the fitted GGX misses the Phong lobe's radiance by ~100% (issue 16,
    # defect 9: a conversion that does not represent its source says so)
    assert main(["convert", "phong-to-ggx", "--source", "modified-phong", "--exponents", "100",
                 "--json"]) == 1
    captured = capsys.readouterr()
    doc = json.loads(captured.out)
    assert "0/1 fitting GGX to modified-phong n = 100" in captured.err  # the progress bar
    assert doc["source"] == "modified-phong" and doc["target"] == "ggx"
    assert doc["metric"] == "log" and "hemisphere grid" in doc["geometry"]
    assert doc["max_zenith_deg"] == 80.0
    (row,) = doc["rows"]
    assert row["converged"] and row["blinn_phong_exponent"] == 400.0
    assert row["alpha_closed"] == pytest.approx(math.sqrt(2.0 / 402.0))
    assert 1.0 / FACTOR < row["ratio"] < FACTOR
    assert float(alpha_from_table(doc, 100.0)) == pytest.approx(row["alpha_fit"])
    assert row["radiance_error"] > REPRESENTS_TOL and not row["represents"]
    assert doc["error_measures"]["represents"] == f"radiance_error <= {REPRESENTS_TOL:g}"


def test_cli_and_library_share_the_representation_tolerance():
    from brdf_fit import cli

    assert cli.REPRESENTS_TOL == REPRESENTS_TOL


def _one_line_error(capsys, *fragments):
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("brdf-fit: error:"), err
    for f in fragments:
        assert f in lines[0], lines[0]


def test_cli_bad_source_is_one_line_exit_2(capsys):
    assert main(["convert", "phong-to-ggx", "--source", "ggx"]) == 2
    _one_line_error(capsys, "unknown source 'ggx'", "modified-phong")
    assert main(["convert", "phong-to-ggx", "--source", "nosuch"]) == 2
    _one_line_error(capsys, "unknown source 'nosuch'")
    assert main(["convert", "ggx-to-phong"]) == 2
    _one_line_error(capsys, "unknown conversion", "phong-to-ggx")
    assert main(["convert", "phong-to-ggx", "--exponents", "-1"]) == 2
    _one_line_error(capsys, "exponents must lie in")
    assert main(["convert", "phong-to-ggx", "--metric", "l2"]) == 2
    _one_line_error(capsys, "unknown metric 'l2'")


def test_library_errors_are_named():
    with pytest.raises(ConversionError, match="max_zenith_deg"):
        phong_to_ggx("blinn-phong", [10.0], max_zenith_deg=95.0)
