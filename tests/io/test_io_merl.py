"""MERL binary: exact file layout and channel scales (formats.md 1.1, the public BRDFRead.cpp),
the write -> read round trip at bin centres, index functions, and clear errors for bad files."""

import math

import jax
import numpy as np
import pytest
from _helpers import PEAK_RSS_CODE, peak_kib

from brdf_fit import registry
from brdf_fit.data import DataError
from brdf_fit.io.merl import (
    MERL_DIMS,
    MERL_FILE_SIZE,
    MERL_MISSING,
    MERL_SCALES,
    _half_diff,
    is_merl_file,
    merl_bin_centres,
    merl_indices,
    merl_lookup,
    read_merl,
    read_merl_table,
    write_merl,
)
from data_synth.plans import half_diff_to_io, io_to_half_diff, merl_grid

N = 90 * 90 * 180
#: bins whose centre has both directions above the horizon (counted in test_file_layout)
N_VALID = 1_096_216
#: |fl(fl(f/s)*s) - f| <= ((1+u)^2 - 1)|f| with u = 2^-53: two correctly rounded operations
TWO_ROUNDINGS = 2.0 * 2.0**-53 * (1.0 + 2.0**-53)


def toy_brdf(wi, wo):
    """A smooth, non-reciprocal-looking RGB function (any function of the pair will do)."""
    wi, wo = np.asarray(wi), np.asarray(wo)
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    spec = np.exp(-20.0 * (1.0 - h[:, 2]))
    base = 0.1 + 0.05 * wi[:, 0] * wo[:, 1] + 0.3 * spec
    return base[:, None] * np.array([1.0, 0.7, 0.4]) + 0.01 * wi[:, 2:3]


@pytest.fixture(scope="module")
def toy_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("merl") / "toy.binary"
    write_merl(path, toy_brdf)
    return path


def _raw(path):
    blob = path.read_bytes()
    return np.frombuffer(blob[:12], "<i4"), np.frombuffer(blob, "<f8", offset=12)


def _centre(i, j, k):
    """Bin centre of (i_theta_h, i_theta_d, i_phi_d) by formats.md, written independently:
    wi = rotate(d, y, theta_h), wo = 2 (wi.h) h - wi, phi_h = 0."""
    th = ((i + 0.5) / 90) ** 2 * math.pi / 2
    td = (j + 0.5) / 90 * math.pi / 2
    pd = (k + 0.5) / 180 * math.pi
    d = np.array([math.sin(td) * math.cos(pd), math.sin(td) * math.sin(pd), math.cos(td)])
    wi = np.array([math.cos(th) * d[0] + math.sin(th) * d[2], d[1],
                   -math.sin(th) * d[0] + math.cos(th) * d[2]])
    h = np.array([math.sin(th), 0.0, math.cos(th)])
    return wi, 2.0 * (wi @ h) * h - wi


def test_scales_and_constants_match_brdfread():
    # RED_SCALE 1.0/1500, GREEN_SCALE 1.15/1500, BLUE_SCALE 1.66/1500 (BRDFRead.cpp)
    np.testing.assert_array_equal(MERL_SCALES, [1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
    assert MERL_DIMS == (90, 90, 180)
    assert MERL_FILE_SIZE == 34_992_012 == 12 + 3 * N * 8


def test_file_layout(toy_file):
    assert toy_file.stat().st_size == MERL_FILE_SIZE
    dims, raw = _raw(toy_file)
    np.testing.assert_array_equal(dims, [90, 90, 180])
    assert raw.size == 3 * N
    # channel blocks R, G, B; inside a block ind = k + 180 (j + 90 i); raw = f / scale
    for i, j, k in [(0, 0, 0), (3, 40, 17), (60, 10, 179), (89, 0, 90), (10, 89, 0)]:
        wi, wo = _centre(i, j, k)
        ind = k + 180 * (j + 90 * i)
        if wi[2] > 0 and wo[2] > 0:
            f = toy_brdf(wi[None], wo[None])[0]
            for c in range(3):
                np.testing.assert_allclose(raw[ind + c * N], f[c] / MERL_SCALES[c],
                                           rtol=1e-13)
        else:
            np.testing.assert_array_equal(raw[[ind, ind + N, ind + 2 * N]], -1.0)
    # bins with a centre below the horizon are exactly -1 in all channels
    wi, wo = merl_bin_centres()
    below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
    blocks = raw.reshape(3, N)
    np.testing.assert_array_equal(blocks[:, below], -1.0)
    assert (blocks[:, ~below] >= 0).all()
    # closed form: with phi_h = 0, wi.z, wo.z = cos th cos td -/+ sin th sin td cos pd
    i, j, k = (g.ravel() for g in np.meshgrid(np.arange(90), np.arange(90), np.arange(180),
                                              indexing="ij"))
    th, td, pd = ((i + 0.5) / 90) ** 2 * math.pi / 2, (j + 0.5) / 90 * math.pi / 2, \
        (k + 0.5) / 180 * math.pi
    np.testing.assert_array_equal(~below, np.tan(th) * np.tan(td) * np.abs(np.cos(pd)) < 1)
    assert int((~below).sum()) == N_VALID


def test_reader_applies_channel_scales_to_handmade_file(tmp_path):
    # independent of the writer: raw 1500 everywhere reads as (1, 1.15, 1.66) / sr
    raw = np.full(3 * N, 1500.0)
    raw[N + 5] = -1.0  # one missing green bin: (i, j, k) = (0, 0, 5)
    p = tmp_path / "hand.binary"
    p.write_bytes(np.array([90, 90, 180], "<i4").tobytes() + raw.astype("<f8").tobytes())
    assert is_merl_file(p)
    table = read_merl_table(p)
    assert table.shape == (3, 90, 90, 180)
    np.testing.assert_allclose(table[:, 1, 2, 3], [1.0, 1.15, 1.66], rtol=1e-15)
    assert table[1, 0, 0, 5] == MERL_MISSING and table[0, 0, 0, 5] == 1500.0 / 1500.0
    d = read_merl(p)
    # read_merl keeps bins with all channels present and both centre directions above horizon
    assert d.n == N_VALID - 1
    assert d.metadata["n_missing_bins"] == N - d.n
    assert d.channels == ("R", "G", "B")


def test_roundtrip_exact_at_bin_centres(toy_file):
    d = read_merl(toy_file)
    wi, wo = merl_bin_centres()
    keep = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    np.testing.assert_array_equal(d.wi, wi[keep])
    np.testing.assert_array_equal(d.wo, wo[keep])
    f = toy_brdf(d.wi, d.wo)
    # the stored raw is fl(f/s) and the reader returns fl(raw*s): two roundings, nothing more
    rel = np.abs(d.value - f) / f
    assert rel.max() <= TWO_ROUNDINGS
    d.validate()
    # nearest-bin lookup at the centres returns the stored values exactly
    table = read_merl_table(toy_file)
    np.testing.assert_array_equal(merl_lookup(table, d.wi, d.wo), d.value)
    # and reciprocity: swapping wi and wo lands in the same bin (phi_d folds onto [0, pi))
    np.testing.assert_array_equal(merl_lookup(table, d.wo, d.wi), d.value)


def test_every_bin_centre_maps_to_its_own_bin():
    wi, wo = merl_bin_centres()
    ith, itd, ipd = merl_indices(wi, wo)
    grid = np.stack(np.meshgrid(np.arange(90), np.arange(90), np.arange(180), indexing="ij"),
                    -1).reshape(-1, 3)
    np.testing.assert_array_equal(np.stack([ith, itd, ipd], -1), grid)
    # the two half/difference implementations agree (merl and data_synth.plans)
    sl = slice(0, None, 97)
    th, td, pd = _half_diff(wi[sl], wo[sl])
    th2, _, td2, pd2 = io_to_half_diff(wi[sl], wo[sl])
    np.testing.assert_allclose(np.stack([th, td, pd]), np.stack([th2, td2, pd2]), atol=1e-12)
    # merl_grid (the measurement plan) uses the same positions
    plan = merl_grid(subsample=7)
    i, j, k = plan.extra["index"].T
    flat = k + 180 * (j + 90 * i)
    np.testing.assert_allclose(plan.wi, wi[flat], atol=1e-15)
    np.testing.assert_allclose(plan.wo, wo[flat], atol=1e-15)


def test_index_functions_by_hand():
    s30, c30 = 0.5, math.sqrt(3) / 2
    # mirror pair: theta_h = 0 -> i_theta_h 0; theta_d = 30 deg -> 30; phi_d = 0 -> 0
    got = merl_indices([[s30, 0, c30]], [[-s30, 0, c30]])
    assert [int(g[0]) for g in got] == [0, 30, 0]
    # wi = wo at 45 deg: theta_h = 45 deg, floor(sqrt(0.5) * 90) = 63 (non-linear map); theta_d 0
    w = [[math.sqrt(0.5), 0, math.sqrt(0.5)]]
    assert [int(g[0]) for g in merl_indices(w, w)] == [63, 0, 0]
    # normal incidence and view: all zero
    assert [int(g[0]) for g in merl_indices([[0, 0, 1.0]], [[0, 0, 1.0]])] == [0, 0, 0]
    # phi_d < 0 is folded by +pi: the pair with d = (theta_d, -phi) and (theta_d, pi - phi)
    th, td = 0.3, 0.7
    for pd in (-2.5, -1.0, -0.2):
        a = merl_indices(*half_diff_to_io(th, 0.0, td, pd))
        b = merl_indices(*half_diff_to_io(th, 0.0, td, pd + math.pi))
        assert [int(x[0]) for x in a] == [int(x[0]) for x in b]
        assert int(a[2][0]) == math.floor((pd + math.pi) / math.pi * 180)


def test_lookup_below_horizon_and_shape_errors(toy_file):
    table = read_merl_table(toy_file)
    out = merl_lookup(table, [[0.6, 0, -0.8], [0.6, 0, 0.8]], [[0, 0, 1.0], [0, 0.6, 0.8]])
    assert (out[0] == MERL_MISSING).all() and (out[1] > 0).all()
    with pytest.raises(DataError, match=r"table must have shape \(3, 90, 90, 180\)"):
        merl_lookup(table[:, :10], [[0, 0, 1.0]], [[0, 0, 1.0]])
    with pytest.raises(DataError, match=r"wi and wo must be \(N, 3\)"):
        merl_lookup(table, np.zeros((2, 3)), np.zeros((3, 3)))


def test_roundtrip_of_a_registry_model(tmp_path):
    model = registry.get("ggx-conductor").build(alpha=0.2)
    p = tmp_path / "ggx.binary"
    write_merl(p, model)
    d = read_merl(p)
    sub = d.subset(np.arange(0, d.n, 101))
    f = np.asarray(jax.jit(lambda a, b: model.eval(a, b))(sub.wi, sub.wo))  # eager is slow
    assert f.min() > 0
    np.testing.assert_allclose(sub.value, f, rtol=1e-13, atol=0)


# ----------------------------------------------------------------------------- bad files


def _header(dims=(90, 90, 180)):
    return np.asarray(dims, "<i4").tobytes()


def test_truncated_and_malformed_files(toy_file, tmp_path):
    blob = toy_file.read_bytes()
    cases = {
        "truncated.binary": (blob[:-8], r"wrong size 34,992,004 bytes.*the file is truncated"),
        "trailing.binary": (blob + b"\0" * 8, r"the file is 8 bytes too long"),
        "tiny.binary": (blob[:7], r"7 bytes is too short for a MERL header"),
        "dims.binary": (_header((90, 90, 360)) + blob[12:],
                        r"MERL header dims \(90, 90, 360\), expected \(90, 90, 180\)"),
    }
    for name, (data, match) in cases.items():
        p = tmp_path / name
        p.write_bytes(data)
        with pytest.raises(DataError, match=match) as info:
            read_merl(p)
        assert str(p) in str(info.value)
        assert not is_merl_file(p)
    raw = np.zeros(3 * N)
    raw[2 * N + 7 + 180 * (3 + 90 * 2)] = np.nan
    p = tmp_path / "nan.binary"
    p.write_bytes(_header() + raw.astype("<f8").tobytes())
    with pytest.raises(DataError, match=r"non-finite value nan in channel B at bin "
                                        r"\(i_theta_h=2, i_theta_d=3, i_phi_d=7\)"):
        read_merl_table(p)
    p = tmp_path / "empty.binary"  # every bin missing: said so (it was "no samples left
    p.write_bytes(_header() + np.full(3 * N, -1.0).astype("<f8").tobytes())  # after a cut")
    with pytest.raises(DataError, match=r"empty.binary: no valid bin"):
        read_merl(p)
    with pytest.raises(DataError, match="cannot read MERL file"):
        read_merl(tmp_path / "missing.binary")
    assert not is_merl_file(tmp_path / "missing.binary")


def test_huge_file_refused_before_its_payload_is_read(tmp_path):
    """A sparse 6 GiB file with a valid header is refused from its size alone: the reading
    process's peak memory stays that of its imports (it read the 6 GiB, 6.5 GB of memory,
    before refusing it; issue 45)."""
    import subprocess
    import sys

    p = tmp_path / "huge.binary"
    with open(p, "wb") as fh:
        fh.write(_header())
        fh.truncate(6 * 2**30)
    code = PEAK_RSS_CODE + (
        "from brdf_fit.io.merl import read_merl\n"
        "from brdf_fit.data import DataError\n"
        "try:\n"
        "    read_merl(_s.argv[1])\n"
        "except DataError as e:\n"
        "    print(e)\n"
        "_peak()\n")
    out = subprocess.run([sys.executable, "-c", code, str(p)], capture_output=True, text=True,
                         check=True)
    message = out.stdout.strip()
    assert "wrong size 6,442,450,944 bytes" in message and "too long" in message, message
    assert peak_kib(out.stderr) < 300 * 1024, out.stderr  # KiB; the imports take ~100 MB


def test_writer_rejects_bad_model_values(tmp_path):
    def negative(wi, wo):
        v = toy_brdf(wi, wo)
        v[wi[:, 2] < 0.5] *= -1.0
        return v

    with pytest.raises(DataError, match=r"model value at bin .* finite non-negative"):
        write_merl(tmp_path / "neg.binary", negative)
    with pytest.raises(DataError, match=r"returned shape \(.*, 2\).*expected \(N, 3\)"):
        write_merl(tmp_path / "shape.binary", lambda wi, wo: np.ones((wi.shape[0], 2)))
    # a one-channel model is broadcast to grey RGB
    p = tmp_path / "grey.binary"
    write_merl(p, lambda wi, wo: np.full(wi.shape[0], 0.25))
    t = read_merl_table(p)
    np.testing.assert_allclose(t[:, 0, 0, 0], 0.25, rtol=TWO_ROUNDINGS)


def test_interpolation_between_bin_centres(tmp_path):
    """merl_interpolate: a bin centre returns its bin; between centres the value follows the
    trilinear formula (checked along phi_d across its wrap, bins 179 and 0); a smooth model's
    file is interpolated closer to the model than the nearest bin; below the horizon missing."""
    from _helpers import random_dirs

    from brdf_fit.io.merl import (
        merl_bin_centres,
        merl_interpolate,
        read_merl_table,
    )

    model = registry.get("ggx").build(alpha=0.35, f0=np.array([0.9, 0.6, 0.3]))
    path = tmp_path / "ggx.binary"
    write_merl(path, model)
    table = read_merl_table(path)
    wi, wo = merl_bin_centres()
    ok = np.flatnonzero((wi[:, 2] > 0) & (wo[:, 2] > 0))[::1009]
    np.testing.assert_allclose(merl_interpolate(table, wi[ok], wo[ok]),
                               merl_lookup(table, wi[ok], wo[ok]), rtol=1e-10)
    # phi_d = 0 (the fold): halfway between the centres of bins 179 and 0, at the centres of
    # theta_h bin 40 and theta_d bin 30
    h, d = 40, 30
    mid_i, mid_o = half_diff_to_io(((h + 0.5) / 90) ** 2 * math.pi / 2, 0.0,
                                   (d + 0.5) / 90 * math.pi / 2, 0.0)
    got = merl_interpolate(table, mid_i, mid_o)
    np.testing.assert_allclose(got[0], 0.5 * (table[:, h, d, 0] + table[:, h, d, 179]),
                               rtol=1e-9)
    rng = np.random.default_rng(7)
    ri, ro = random_dirs(rng, 4000, lo=0.05), random_dirs(rng, 4000, lo=0.05)
    truth = np.asarray(model.eval(ri, ro))
    err_interp = np.abs(np.log(merl_interpolate(table, ri, ro) / truth))
    err_nearest = np.abs(np.log(merl_lookup(table, ri, ro) / truth))
    assert np.median(err_interp) < 0.5 * np.median(err_nearest)
    below = merl_interpolate(table, np.array([[0.0, 0.6, -0.8]]), np.array([[0.0, 0.0, 1.0]]))
    assert (below == -1.0).all()
