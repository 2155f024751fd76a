"""RGL-EPFL ``.bsdf`` materials (brdf_fit.io.rgl, issue 44): the tensor file round trip, the
reader against Mitsuba 3's own ``measured`` plugin on files written for the test, hostile
files refused with one line, and ``io.read`` giving GonioData at the default directions.

The materials are random tables (not physical ones: the reader's job is to evaluate what a file
holds exactly as the plugin does), in the three layouts the plugin distinguishes: isotropic
(one ``phi_i``; tables symmetric in azimuth, ``ndf`` and ``sigma`` independent of it, as an
isotropic material's are), anisotropic over the full circle, and measured over half of it
(the plugin's azimuth reduction 2)."""

import numpy as np
import pytest

from brdf_fit.core.limits import ENV as MEMORY_ENV
from brdf_fit.data import DataError
from brdf_fit.io import read
from brdf_fit.io.rgl import (
    DEFAULT_PHI_O_DEG,
    DEFAULT_THETA_O_DEG,
    RGLMaterial,
    read_rgl,
    read_tensor_file,
    write_tensor_file,
)

#: relative agreement with the plugin: it computes in float32 through a chain of square roots,
#: arc functions and CDF quotients (measured: at most 8.5e-6, median 3.5e-7, over 2,400 pairs
#: of the three layouts; float32's unit roundoff is 6e-8)
MITSUBA_RTOL = 3e-5


def _material_fields(kind: str, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    n_theta, rows, cols, n = 5, 9, 7, 8
    theta = np.linspace(0.0, 1.45, n_theta).astype(np.float32)
    phi = {"iso": np.zeros(1), "aniso": np.linspace(-np.pi, np.pi, 5),
           "half": np.linspace(-np.pi, 0.0, 4)}[kind].astype(np.float32)

    def positive(*shape, s=0.7):
        return np.exp(rng.normal(0.0, s, shape)).astype(np.float32)

    vndf = positive(phi.size, n_theta, rows, cols)
    rgb = positive(phi.size, n_theta, 3, n, n)
    ndf, sigma = positive(11, 13, s=0.5), positive(10, 12, s=0.5)
    if kind == "iso":  # rows are the azimuth: symmetric (phi -> -phi), or no dependence
        vndf = 0.5 * (vndf + vndf[:, :, ::-1])
        rgb = 0.5 * (rgb + rgb[:, :, :, ::-1])
        ndf, sigma = (np.repeat(t[:1], t.shape[0], axis=0) for t in (ndf, sigma))
    return dict(description=f"test material ({kind})", jacobian=np.array([1], np.uint8),
                theta_i=theta, phi_i=phi, ndf=ndf, sigma=sigma, vndf=vndf,
                luminance=positive(phi.size, n_theta, n, n), rgb=rgb)


@pytest.fixture(scope="module", params=["iso", "aniso", "half"])
def material_file(request, tmp_path_factory):
    path = tmp_path_factory.mktemp("rgl") / f"{request.param}.bsdf"
    write_tensor_file(path, **_material_fields(request.param, seed=44))
    return path


def _directions(rng, n, grazing=False):
    mu = rng.uniform(1e-4, 0.02, n) if grazing else rng.uniform(0.02, 1.0, n)
    phi = rng.uniform(-np.pi, np.pi, n)
    s = np.sqrt(1.0 - mu * mu)
    return np.stack([s * np.cos(phi), s * np.sin(phi), mu], -1)


def test_tensor_file_round_trip(tmp_path):
    fields = {"text": "héllo", "a": np.arange(7, dtype=np.float32).reshape(7, 1),
              "b": np.array([[1, 2], [3, 4]], np.uint16), "c": np.float64(2.5) * np.ones(3),
              "flag": np.array([1], np.uint8)}
    write_tensor_file(tmp_path / "t.bsdf", **fields)
    back = read_tensor_file(tmp_path / "t.bsdf")
    assert list(back) == list(fields)
    assert bytes(back["text"]).decode() == "héllo"
    for k in ("a", "b", "c", "flag"):
        assert back[k].dtype == fields[k].dtype
        np.testing.assert_array_equal(back[k], fields[k])


def test_agrees_with_mitsuba_measured_plugin(material_file):
    mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (the test extra)")
    from brdf_fit.convert.mitsuba import VARIANT

    mi.set_variant(VARIANT)
    plugin = mi.load_dict({"type": "measured", "filename": str(material_file)})
    ours = RGLMaterial(read_tensor_file(material_file), str(material_file))
    rng = np.random.default_rng(7)
    ctx = mi.BSDFContext()
    for grazing in (False, True):
        wi, wo = _directions(rng, 200), _directions(rng, 200, grazing)
        want = []
        for a, b in zip(wi, wo, strict=True):
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*a)
            v = plugin.eval(ctx, si, mi.Vector3f(*b))
            want.append([v[0], v[1], v[2]])
        want = np.array(want)
        got = ours.eval_cos(wi, wo)
        assert np.all(want > 0)
        np.testing.assert_allclose(got, want, rtol=MITSUBA_RTOL, atol=0)
        # the BRDF is the plugin's value over the outgoing cosine
        np.testing.assert_allclose(ours.eval(wi, wo), got / wo[:, 2:3], rtol=1e-12)
    # below the surface: zero, as in the plugin
    assert np.all(ours.eval_cos(np.array([[0.0, 0.6, -0.8]]), np.array([[0.0, 0.0, 1.0]])) == 0)


def test_negative_control_a_reader_without_the_jacobian_disagrees(material_file):
    """The comparison above can fail: the same reader with the file's jacobian flag ignored
    (the ndf / (4 sigma) factor left out) is far from the plugin's value."""
    ours = RGLMaterial(read_tensor_file(material_file), str(material_file))
    rng = np.random.default_rng(8)
    wi, wo = _directions(rng, 50), _directions(rng, 50)
    with_it = ours.eval_cos(wi, wo)
    ours.jacobian = False
    assert np.max(np.abs(ours.eval_cos(wi, wo) / with_it - 1.0)) > 100 * MITSUBA_RTOL


def test_read_gives_gonio_data_at_the_default_directions(material_file):
    data = read(material_file)
    fields = read_tensor_file(material_file)
    n_inc = np.sum(fields["theta_i"] < np.radians(89.0))
    n_inc *= 1 if fields["phi_i"].size <= 2 else fields["phi_i"].size
    assert len(data.value) == n_inc * DEFAULT_THETA_O_DEG.size * DEFAULT_PHI_O_DEG.size
    assert data.channels == ("R", "G", "B")
    assert data.metadata["format"] == "rgl"
    assert np.all(np.isfinite(data.value)) and np.all(data.value > 0)
    np.testing.assert_allclose(np.linalg.norm(data.wi, axis=1), 1.0, rtol=1e-12)
    # directions of one's own choosing
    wi, wo = data.wi[:5], data.wo[-5:]
    np.testing.assert_array_equal(read_rgl(material_file, wi, wo).value,
                                  RGLMaterial(fields).eval(wi, wo))


def test_hostile_files_are_refused_with_one_line(tmp_path, monkeypatch):
    good = tmp_path / "good.bsdf"
    write_tensor_file(good, **_material_fields("iso", seed=1))
    raw = good.read_bytes()
    cases = {
        "empty.bsdf": (b"", "not a tensor file"),
        "magic.bsdf": (b"tensor_fill\0" + raw[12:], "not a tensor file"),
        "version.bsdf": (raw[:12] + b"\x02\x00" + raw[14:], "version 2.0"),
        "truncated.bsdf": (raw[: len(raw) // 2], "past the end of the file"),
        "header.bsdf": (raw[:40], "truncated"),
        "fields.bsdf": (raw[:14] + (10**6).to_bytes(4, "little") + raw[18:], "fields"),
    }
    for name, (content, fragment) in cases.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(DataError, match=fragment) as e:
            read(tmp_path / name)
        assert name in str(e.value) and "\n" not in str(e.value)
    # a field that declares 2^40 floats (the file is small): refused before any allocation
    big = bytearray(raw)
    at = raw.index(b"vndf") + 4 + 2 + 1 + 8  # the first extent of 'vndf'
    big[at:at + 8] = (2**40).to_bytes(8, "little")
    (tmp_path / "huge.bsdf").write_bytes(bytes(big))
    with pytest.raises(DataError, match="past the end"):
        read(tmp_path / "huge.bsdf")
    # the memory limit: a whole, consistent file larger than the limit allows
    monkeypatch.setenv(MEMORY_ENV, "1k")
    with pytest.raises(DataError, match="memory limit"):
        read(good)
    monkeypatch.delenv(MEMORY_ENV)
    # a tensor file that is not a material
    write_tensor_file(tmp_path / "other.bsdf", a=np.zeros(3, np.float32))
    with pytest.raises(DataError, match="not an RGL material: no field theta_i"):
        read(tmp_path / "other.bsdf")
