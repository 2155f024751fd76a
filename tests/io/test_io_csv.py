"""Gonioreflectometer CSV: round trips (RGB, mono, spectral, sigma, weights, radians), quantity
conversions (BRF, BRDF*cos), the specular convention, and bad input named by line and column."""

import math

import numpy as np
import pytest

from brdf_fit.data import DataError, GonioData, wavelength_channels
from brdf_fit.io.csv import read_csv, write_csv


def _random_data(n=40, channels=("R", "G", "B"), seed=0, sigma=False, weight=False, **kw):
    rng = np.random.default_rng(seed)
    nc = len(channels)
    theta_i = rng.uniform(0.0, 85.0, n)
    theta_o = rng.uniform(0.0, 85.0, n)
    theta_i[0], theta_o[1] = 0.0, 0.0  # the pole, where arccos is least accurate
    value = rng.lognormal(-1.0, 1.0, (n, nc))
    extra = {}
    if sigma:
        extra["sigma"] = 0.01 * value + 1e-4
    if weight:
        w = rng.uniform(0.5, 2.0, (n, nc))
        w[3] = 0.0
        extra["weight"] = w
    return GonioData.from_angles_deg(theta_i, rng.uniform(0, 360, n), theta_o,
                                     rng.uniform(-180, 180, n), value, channels=channels,
                                     **extra, **kw)


def _write(tmp_path, text, name="m.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def _assert_same(a, b, rtol=0.0):
    # directions go through angles (atan2, degrees) and back: a few ulps of error
    np.testing.assert_allclose(a.wi, b.wi, rtol=0, atol=2e-15)
    np.testing.assert_allclose(a.wo, b.wo, rtol=0, atol=2e-15)
    np.testing.assert_allclose(a.value, b.value, rtol=rtol, atol=0)
    np.testing.assert_array_equal(a.weight, b.weight)
    assert a.channels == b.channels
    if a.sigma is None:
        assert b.sigma is None
    else:
        np.testing.assert_allclose(a.sigma, b.sigma, rtol=rtol, atol=0)


# ----------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("angles", ["deg", "rad"])
def test_rgb_roundtrip_with_sigma_weight_and_metadata(tmp_path, angles):
    meta = {"instrument": {"name": "virtual", "arms": 4}, "operator": "me", "temp_C": 21.5}
    d = _random_data(sigma=True, weight=True, metadata=meta)
    p = tmp_path / "rgb.csv"
    write_csv(d, p, angles=angles)
    header = next(line for line in p.read_text().splitlines() if not line.startswith("#"))
    cols = header.split(",")
    angle_cols = ["theta_i", "phi_i", "theta_o", "phi_o"]
    if angles == "rad":
        angle_cols = [c + "_rad" for c in angle_cols]
    assert cols[:4] == angle_cols
    assert cols[4:] == ["brdf_r", "brdf_g", "brdf_b", "sigma_r", "sigma_g", "sigma_b",
                        "weight_r", "weight_g", "weight_b"]
    r = read_csv(p)
    # values, sigma and weights are written with 17 significant digits: exact
    _assert_same(d, r)
    np.testing.assert_array_equal(r.value, d.value)
    assert r.metadata["instrument"] == meta["instrument"]
    assert r.metadata["operator"] == "me" and r.metadata["temp_C"] == 21.5
    assert r.metadata["format"] == "csv" and r.metadata["quantity_in_file"] == "brdf"


def test_mono_roundtrip_uses_unsuffixed_column(tmp_path):
    d = _random_data(channels=("Y",))
    p = tmp_path / "y.csv"
    write_csv(d, p)
    assert "theta_i,phi_i,theta_o,phi_o,brdf" in p.read_text().splitlines()
    r = read_csv(p)
    _assert_same(d, r)
    assert r.channels == ("Y",)


def test_uniform_weight_is_one_column(tmp_path):
    d = _random_data(channels=("Y",))
    w = np.ones((d.n, 1))
    w[5] = 0.0
    d = GonioData(d.wi, d.wo, d.value, weight=w, channels=("Y",))
    p = tmp_path / "w.csv"
    write_csv(d, p)
    assert p.read_text().splitlines()[1].endswith(",brdf,weight")
    np.testing.assert_array_equal(read_csv(p).weight, w)


def test_spectral_roundtrip_and_channel_order(tmp_path):
    chans = wavelength_channels([400, 550.5, 700])
    d = _random_data(channels=chans)
    p = tmp_path / "s.csv"
    write_csv(d, p)
    assert "brdf_400nm,brdf_550.5nm,brdf_700nm" in p.read_text()
    r = read_csv(p)
    _assert_same(d, r)
    np.testing.assert_allclose(r.wavelengths_nm, [400.0, 550.5, 700.0])

    # columns out of wavelength order: channels are sorted, values follow their columns
    p2 = _write(tmp_path, "theta_i,phi_i,theta_o,phi_o,brdf_700nm,brdf_400nm\n"
                          "10,0,20,180,0.7,0.4\n", "s2.csv")
    r2 = read_csv(p2)
    assert r2.channels == ("400nm", "700nm")
    np.testing.assert_array_equal(r2.value, [[0.4, 0.7]])


@pytest.mark.parametrize("quantity", ["brf", "brdfcos"])
def test_quantity_roundtrip(tmp_path, quantity):
    d = _random_data(sigma=True)
    p = tmp_path / "q.csv"
    write_csv(d, p, quantity=quantity)
    text = p.read_text()
    assert f"# quantity: {quantity}" in text and f"{quantity}_r" in text
    r = read_csv(p)
    assert r.metadata["quantity_in_file"] == quantity
    _assert_same(d, r, rtol=4e-15)


def test_quantities_are_converted_to_brdf(tmp_path):
    # BRF = pi * BRDF; brdfcos = BRDF * cos(theta_o); sigma columns convert with the values
    rows = "30,0,60,180,{v},{s}\n0,0,0,0,{v},{s}\n"
    head = "theta_i,phi_i,theta_o,phi_o,{q},sigma\n"
    brf = read_csv(_write(tmp_path, head.format(q="brf") + rows.format(v=1.0, s=0.1)))
    np.testing.assert_allclose(brf.value[:, 0], 1.0 / math.pi, rtol=1e-15)
    np.testing.assert_allclose(brf.sigma[:, 0], 0.1 / math.pi, rtol=1e-15)
    cosq = read_csv(_write(tmp_path, head.format(q="brdfcos") + rows.format(v=0.5, s=0.05)))
    np.testing.assert_allclose(cosq.value[:, 0], [0.5 / 0.5, 0.5], rtol=1e-14)
    np.testing.assert_allclose(cosq.sigma[:, 0], [0.05 / 0.5, 0.05], rtol=1e-14)
    plain = read_csv(_write(tmp_path, head.format(q="brdf") + rows.format(v=0.5, s=0.05)))
    np.testing.assert_array_equal(plain.value[:, 0], 0.5)


def test_value_family_takes_declared_quantity(tmp_path):
    body = "theta_i,phi_i,theta_o,phi_o,value\n30,0,60,180,1.0\n"
    p = _write(tmp_path, "# quantity: brf\n" + body)
    np.testing.assert_allclose(read_csv(p).value, 1.0 / math.pi, rtol=1e-15)
    # the argument overrides the comment
    np.testing.assert_allclose(read_csv(p, quantity="brdfcos").value, 2.0, rtol=1e-14)
    # no declaration: BRDF
    p2 = _write(tmp_path, body, "plain.csv")
    np.testing.assert_array_equal(read_csv(p2).value, 1.0)


def test_declared_quantity_contradicting_columns_is_an_error(tmp_path):
    p = _write(tmp_path, "# quantity: brf\ntheta_i,phi_i,theta_o,phi_o,brdf\n30,0,60,180,1\n")
    with pytest.raises(DataError, match=r"line 2: declared quantity 'brf' contradicts"):
        read_csv(p)
    p2 = _write(tmp_path, "# quantity: radiance\ntheta_i,phi_i,theta_o,phi_o,value\n"
                          "30,0,60,180,1\n", "r.csv")
    with pytest.raises(DataError, match=r"unknown '# quantity: radiance'"):
        read_csv(p2)


def test_specular_direction_convention(tmp_path):
    # phi_o = phi_i + 180 at equal zenith is the mirror direction: wo = (-wi_x, -wi_y, wi_z)
    p = _write(tmp_path, "theta_i,phi_i,theta_r,phi_r,brdf\n30,20,30,200,1\n")
    d = read_csv(p)
    np.testing.assert_allclose(d.wo[0], [-d.wi[0, 0], -d.wi[0, 1], d.wi[0, 2]], atol=1e-15)
    np.testing.assert_allclose(d.wi[0], [0.5 * math.cos(math.radians(20)),
                                         0.5 * math.sin(math.radians(20)),
                                         math.sqrt(3) / 2], atol=1e-15)


def test_radian_columns_and_option(tmp_path):
    deg = read_csv(_write(tmp_path, "theta_i,phi_i,theta_o,phi_o,brdf\n30,0,45,180,1\n"))
    suffix = read_csv(_write(
        tmp_path, "theta_i_rad,phi_i_rad,theta_o_rad,phi_o_rad,brdf\n"
                  f"{math.pi / 6!r},0,{math.pi / 4!r},{math.pi!r},1\n", "a.csv"))
    option = read_csv(_write(
        tmp_path, "theta_i,phi_i,theta_o,phi_o,brdf\n"
                  f"{math.pi / 6!r},0,{math.pi / 4!r},{math.pi!r},1\n", "b.csv"), angles="rad")
    mixed = read_csv(_write(
        tmp_path, "theta_i_deg,phi_i,theta_o,phi_o,brdf\n"
                  f"30,0,{math.pi / 4!r},{math.pi!r},1\n", "c.csv"), angles="rad")
    for other in (suffix, option, mixed):
        np.testing.assert_allclose(other.wi, deg.wi, atol=1e-15)
        np.testing.assert_allclose(other.wo, deg.wo, atol=1e-15)
    with pytest.raises(ValueError, match="angles must be 'deg' or 'rad'"):
        read_csv(tmp_path / "a.csv", angles="grad")


@pytest.mark.parametrize("delim", [",", "\t", ";", "  "])
def test_delimiters_comments_blank_lines_and_case(tmp_path, delim):
    cols = ["Theta_I", "PHI_I", "theta_o", "phi_o", "BRDF_R", "brdf_g", "brdf_b", "note"]
    text = ("# comment line without a key\n\n# lab: \"bench 3\"\n" + delim.join(cols) + "\n"
            + delim.join(["10", "0", "20", "180", "0.1", "0.2", "0.3", "x"]) + "\n\n"
            + delim.join(["0", "0", "0", "0", "1", "2", "3", "y"]) + "\n")
    d = read_csv(_write(tmp_path, text))
    assert d.channels == ("R", "G", "B") and d.n == 2
    np.testing.assert_array_equal(d.value, [[0.1, 0.2, 0.3], [1, 2, 3]])
    assert d.metadata["lab"] == "bench 3"


def test_mono_sigma_shared_by_all_channels(tmp_path):
    d = read_csv(_write(tmp_path, "theta_i,phi_i,theta_o,phi_o,brdf_r,brdf_g,brdf_b,sigma\n"
                                  "10,0,20,180,0.1,0.2,0.3,0.01\n"))
    np.testing.assert_array_equal(d.sigma, [[0.01, 0.01, 0.01]])


def test_masked_rows_may_be_at_the_horizon_or_negative(tmp_path):
    d = read_csv(_write(tmp_path, "theta_i,phi_i,theta_o,phi_o,brdf,weight\n"
                                  "10,0,90,180,-5,0\n10,0,20,180,0.5,1\n"))
    np.testing.assert_array_equal(d.weight[:, 0], [0.0, 1.0])


def test_negative_within_noise_is_accepted(tmp_path):
    d = read_csv(_write(tmp_path, "theta_i,phi_i,theta_o,phi_o,brdf,sigma\n"
                                  "10,0,20,180,-0.02,0.01\n"))
    assert d.value[0, 0] == -0.02


# ----------------------------------------------------------------------------- bad input

H = "theta_i,phi_i,theta_o,phi_o,brdf_r,brdf_g,brdf_b\n"
OK = "10,0,20,180,0.1,0.2,0.3\n"


@pytest.mark.parametrize("text,match", [
    ("theta_i,phi_i,theta_o,brdf\n10,0,20,0.1\n", r"line 1: missing column phi_o"),
    ("theta_i,phi_i,theta_o,phi_o,foo\n10,0,20,180,0.1\n", r"line 1: missing value column"),
    ("# c\n" + H + OK + "10,0,95,180,0.1,0.2,0.3\n",
     r"line 4, column 'theta_o': theta = 95 deg is out of range \[0, 90\] deg "
     r"\(below the horizon\)"),
    (H + OK + "-5,0,20,180,0.1,0.2,0.3\n", r"line 3, column 'theta_i': theta = -5 deg"),
    (H + "10,400,20,180,0.1,0.2,0.3\n", r"line 2, column 'phi_i': phi = 400 deg is out of"),
    (H + OK + "10,0,90,180,0.1,0.2,0.3\n",
     r"line 3, column 'theta_o': wo is at or below the horizon \(theta = 90 deg\)"),
    (H + OK + OK + "10,0,20,180,0.1,nan,0.3\n",
     r"line 4, column 'brdf_g': 'nan' is not a finite number"),
    (H + "10,0,20,180,0.1,inf,0.3\n", r"line 2, column 'brdf_g': 'inf' is not a finite"),
    (H + "10,0,20,180,0.1,0.2,abc\n", r"line 2, column 'brdf_b': non-numeric cell 'abc'"),
    (H + "10,0,20,180,0.1,,0.3\n", r"line 2, column 'brdf_g': empty cell"),
    (H + OK + "10,0,20,180,0.1,0.2,-0.3\n",
     r"line 3, column 'brdf_b': value .* is negative \(no sigma given"),
    (H + "10,0,20,180,0.1,0.2\n", r"line 2: 6 cells, but the header \(line 1\) has 7 columns"),
    ("theta_i,phi_i,theta_o,phi_o,brdf,brdf\n10,0,20,180,1,1\n", r"line 1: duplicate column"),
    ("theta_i,phi_i,theta_o,theta_o_rad,phi_o,brdf\n10,0,20,0.3,180,1\n",
     r"line 1: columns 'theta_o' and 'theta_o_rad' give the same angle"),
    ("theta_i,phi_i,theta_o,phi_o,brdf,brf\n10,0,20,180,1,1\n", r"several families"),
    ("theta_i,phi_i,theta_o,phi_o,brdf,brdf_r\n10,0,20,180,1,1\n",
     r"both an unsuffixed 'brdf' column and per-channel columns"),
    ("theta_i,phi_i,theta_o,phi_o,brdf_r,brdf_g,sigma_r,sigma_b\n10,0,20,180,1,1,.1,.1\n",
     r"sigma column\(s\) \['sigma_b'\] match no value channel"),
    ("theta_i,phi_i,theta_o,phi_o,brdf_r,brdf_g,sigma_r\n10,0,20,180,1,1,.1\n",
     r"sigma columns are missing for channel\(s\) \['G'\]"),
    ("theta_i,phi_i,theta_o,phi_o,brdf,sigma\n10,0,20,180,0.5,-0.1\n",
     r"line 2, column 'sigma': sigma must be finite and >= 0"),
    ("theta_i,phi_i,theta_o,phi_o,brdf_r,brdf_g,sigma\n10,0,20,180,-0.001,-0.2,0.01\n",
     r"line 2, column 'brdf_g': value .* more than 5 sigma below 0"),
    ("theta_i,phi_i,theta_o,phi_o,brdf,weight\n10,0,20,180,0.5,-1\n",
     r"line 2, column 'weight': negative weight"),
    ("# only a comment\n\n", r"no header row"),
    (H, r"no data rows after the header \(line 1\)"),
])
def test_bad_input_names_line_column_and_problem(tmp_path, text, match):
    p = _write(tmp_path, text, "bad.csv")
    with pytest.raises(DataError, match=match) as info:
        read_csv(p)
    assert str(info.value).startswith(str(p))


def test_unreadable_files(tmp_path):
    with pytest.raises(DataError, match="cannot read CSV file"):
        read_csv(tmp_path / "missing.csv")
    p = tmp_path / "bin.csv"
    p.write_bytes(b"\x00\xff\xfe\x80" * 10)
    with pytest.raises(DataError, match="not a UTF-8 text file"):
        read_csv(p)


def test_write_rejects_bad_channel_names_and_options(tmp_path):
    d = _random_data(n=3, channels=("a b",))
    with pytest.raises(DataError, match="channel name 'a b'"):
        write_csv(d, tmp_path / "x.csv")
    with pytest.raises(ValueError, match="quantity must be one of"):
        write_csv(_random_data(n=3), tmp_path / "x.csv", quantity="radiance")


def test_theta_90_is_the_horizon():
    # from_angles_deg: theta = 90 deg gives cos exactly 0, so validation rejects it unless masked
    d = GonioData.from_angles_deg([30.0], [0.0], [90.0], [180.0], [0.1])
    assert d.wo[0, 2] == 0.0
    with pytest.raises(DataError, match=r"sample 0: wo is at or below the horizon"):
        d.validate()
    GonioData.from_angles_deg([30.0], [0.0], [90.0], [180.0], [0.1], weight=0.0).validate()
