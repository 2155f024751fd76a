"""brdf_fit.render and ``brdf-fit render``: the sphere under a directional light.

- the centre pixel (the normal faces the camera) is ``f(light, z) cos(theta) E`` of the model,
  evaluated on its own; a black model renders black, and nothing is drawn off the sphere;
- parity with Mitsuba 3 (where installed): the same scene (orthographic camera, unit sphere,
  ``directional`` emitter) through Mitsuba's own sensor rays at the pixel centres, its
  intersection, its emitter sampling and its BSDF (what its ``direct`` integrator computes per
  sample, without the pixel jitter), for ``roughconductor`` and ``roughplastic``: within 1e-3
  relative per pixel away from the silhouette (``n . wo > 0.2``), orientation included (the
  light is off every axis);
- one compiled program per model type and size: new parameter values compile nothing;
- the sRGB encoding of the PNG against IEC 61966-2-1's formula; the command's files, JSON and
  errors;
- the plane at a grazing view: its centre pixel is the model at the camera's direction, a
  Lambertian plane is uniform, nothing is drawn above the horizon, and Mitsuba 3's
  ``perspective`` sensor and ``rectangle`` give the same image (per pixel within 1e-3 relative,
  an anisotropic model included: the frame's orientation).
"""

import json

import matplotlib.image
import numpy as np
import pytest

from brdf_fit import registry
from brdf_fit.cli import main
from brdf_fit.render import (
    FRAME_HALF_WIDTH,
    IRRADIANCE,
    PLANE_CAMERA_DISTANCE,
    PLANE_HALF_WIDTH,
    render_plane,
    render_sphere,
    srgb_8bit,
)
from tests._helpers import counting_compiles

#: the relative per-pixel bound against Mitsuba (issue 46), and where it applies
MITSUBA_REL = 1e-3
SILHOUETTE_COS = 0.2


def test_centre_pixel_is_the_model_at_normal_view():
    m = registry.get("ggx").build(alpha=0.25, f0=np.array([0.9, 0.6, 0.3]))
    img = render_sphere(m, 65, light_zenith_deg=30.0, light_azimuth_deg=60.0)
    t, p = np.radians(30.0), np.radians(60.0)
    light = np.array([[np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)]])
    want = np.asarray(m.eval(light, np.array([[0.0, 0.0, 1.0]])))[0] * np.cos(t) * IRRADIANCE
    np.testing.assert_allclose(img.radiance[32, 32], want, rtol=1e-12)
    assert img.mask[32, 32] and img.cos_view[32, 32] == 1.0


def test_black_model_renders_black_and_nothing_off_the_sphere():
    black = render_sphere(registry.get("lambert").build(rho=0.0), 33)
    assert not black.radiance.any()
    img = render_sphere(registry.get("lambert").build(rho=0.8), 33, light_zenith_deg=0.0)
    assert not img.radiance[~img.mask].any()
    # a Lambertian sphere lit from the camera: 0.8 / pi * cos * pi = 0.8 cos(theta_n)
    np.testing.assert_allclose(img.radiance[img.mask][:, 0], 0.8 * img.cos_view[img.mask],
                               rtol=1e-12)
    # the disc covers the pixels whose centre is within the unit circle
    c = ((np.arange(33) + 0.5) / 33 * 2 - 1) * FRAME_HALF_WIDTH
    np.testing.assert_array_equal(img.mask, c[None, :] ** 2 + c[:, None] ** 2 < 1.0)


def _mitsuba_at_pixel_centres(mi, scene, size: int):
    """``(radiance, hit)`` of a Mitsuba 3 scene under a directional light through its sensor's
    rays at the pixel centres: its intersection, emitter sampling and BSDF (what its ``direct``
    integrator computes per sample, without the pixel jitter)."""
    sensor = scene.sensors()[0]
    ctx = mi.BSDFContext()
    out = np.zeros((size, size, 3))
    hit = np.zeros((size, size), bool)
    for r in range(size):
        for c in range(size):
            ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f((c + 0.5) / size, (r + 0.5) / size),
                                       mi.Point2f(0.5, 0.5))
            si = scene.ray_intersect(ray)
            if not si.is_valid():
                continue
            hit[r, c] = True
            ds, spec = scene.sample_emitter_direction(si, mi.Point2f(0.5, 0.5), True)
            v = si.bsdf().eval(ctx, si, si.to_local(ds.d)) * spec
            out[r, c] = [v[0], v[1], v[2]]
    return out, hit


def _mitsuba_sphere(mi, bsdf: dict, size: int, light, irradiance: float) -> np.ndarray:
    T = mi.ScalarTransform4f
    scene = mi.load_dict({
        "type": "scene",
        "sensor": {"type": "orthographic",
                   "to_world": T().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0])
                   @ T().scale([FRAME_HALF_WIDTH, FRAME_HALF_WIDTH, 1]),
                   "film": {"type": "hdrfilm", "width": size, "height": size}},
        "sphere": {"type": "sphere", "bsdf": bsdf},
        "light": {"type": "directional", "direction": [float(-x) for x in light],
                  "irradiance": {"type": "rgb", "value": float(irradiance)}},
    })
    return _mitsuba_at_pixel_centres(mi, scene, size)


@pytest.mark.parametrize("name", ["mitsuba-roughconductor", "mitsuba-roughplastic"])
def test_matches_mitsuba(name):
    mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (the test extra)")
    from brdf_fit.convert.mitsuba import VARIANT, to_mitsuba

    mi.set_variant(VARIANT)
    params = {"alpha": 0.2}
    img = render_sphere(registry.get(name).build(**params), 33, light_zenith_deg=40.0,
                        light_azimuth_deg=30.0)
    ref, hit = _mitsuba_sphere(mi, to_mitsuba(name, params, verify=False).scene_dict, 33,
                               img.light, IRRADIANCE)
    # the same disc, but for the pixel centres on the rim itself (at 33 pixels 12 of them
    # lie at r = 1 to rounding: a tangent ray, which Mitsuba counts as a hit and we do not)
    c = ((np.arange(33) + 0.5) / 33 * 2 - 1) * FRAME_HALF_WIDTH
    away = np.abs(c[None, :] ** 2 + c[:, None] ** 2 - 1.0) > 1e-5
    np.testing.assert_array_equal(img.mask[away], hit[away])
    inner = img.cos_view > SILHOUETTE_COS
    lit = inner & (ref.max(-1) > 0)
    assert lit.sum() > 300  # most of the disc is compared
    rel = np.abs(img.radiance[..., :3] - ref)[lit] / ref[lit]
    assert rel.max() < MITSUBA_REL, rel.max()
    # where the light is below the surface both are black
    np.testing.assert_array_equal(img.radiance[inner & ~lit][..., :3], 0.0)


def _mitsuba_plane(mi, bsdf: dict, size: int, light, irradiance: float, view_zenith_deg: float,
                   fov_deg: float):
    """The plane scene in Mitsuba 3 through its sensor rays at the pixel centres (as
    :func:`_mitsuba_sphere`): a ``rectangle`` scaled to the square, a ``perspective`` camera."""
    T = mi.ScalarTransform4f
    t = np.radians(view_zenith_deg)
    origin = [0.0, -PLANE_CAMERA_DISTANCE * np.sin(t), PLANE_CAMERA_DISTANCE * np.cos(t)]
    scene = mi.load_dict({
        "type": "scene",
        "sensor": {"type": "perspective", "fov": fov_deg, "fov_axis": "x",
                   "to_world": T().look_at(origin=origin, target=[0, 0, 0], up=[0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": size, "height": size}},
        "plane": {"type": "rectangle", "bsdf": bsdf,
                  "to_world": T().scale([PLANE_HALF_WIDTH, PLANE_HALF_WIDTH, 1])},
        "light": {"type": "directional", "direction": [float(-x) for x in light],
                  "irradiance": {"type": "rgb", "value": float(irradiance)}},
    })
    return _mitsuba_at_pixel_centres(mi, scene, size)


@pytest.mark.parametrize("name, params", [
    ("mitsuba-roughconductor", {"alpha": 0.2}),
    ("mitsuba-roughplastic", {"alpha": 0.2}),
    ("mitsuba-roughconductor-aniso", {"alpha_u": 0.05, "alpha_v": 0.4}),
])
def test_plane_matches_mitsuba(name, params):
    mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (the test extra)")
    from brdf_fit.convert.mitsuba import VARIANT, to_mitsuba

    mi.set_variant(VARIANT)
    # the light off both axes and off the glint, so that a swapped or mirrored axis shows
    img = render_plane(registry.get(name).build(**params), 33, light_zenith_deg=75.0,
                       light_azimuth_deg=70.0)
    ref, hit = _mitsuba_plane(mi, to_mitsuba(name, params, verify=False).scene_dict, 33,
                              img.light, IRRADIANCE, 80.0, 30.0)
    np.testing.assert_array_equal(img.mask, hit)
    assert 0.5 * img.mask.size < img.mask.sum() < img.mask.size  # the horizon is in view
    lit = img.mask & (ref.max(-1) > 0)
    assert lit.sum() == img.mask.sum()
    rel = np.abs(img.radiance[..., :3] - ref)[lit] / ref[lit]
    assert rel.max() < MITSUBA_REL, rel.max()


def test_plane_centre_horizon_and_a_lambertian_plane():
    m = registry.get("ggx").build(alpha=0.3, f0=np.array([0.9, 0.6, 0.3]))
    img = render_plane(m, 33, view_zenith_deg=82.0, light_zenith_deg=60.0,
                       light_azimuth_deg=120.0)
    # the centre pixel's ray is the camera's axis: the plane's origin seen from the camera
    t, tl, pl = np.radians(82.0), np.radians(60.0), np.radians(120.0)
    wo = np.array([[0.0, -np.sin(t), np.cos(t)]])
    light = np.array([[np.sin(tl) * np.cos(pl), np.sin(tl) * np.sin(pl), np.cos(tl)]])
    want = np.asarray(m.eval(light, wo))[0] * np.cos(tl) * IRRADIANCE
    np.testing.assert_allclose(img.radiance[16, 16], want, rtol=1e-12)
    np.testing.assert_allclose(img.cos_view[16, 16], np.cos(t), rtol=1e-12)
    # row r's centre ray looks down by the view's 8 degrees plus its offset (row 0 at the top
    # looks up): above the horizon nothing is drawn, a degree below it everything (the square
    # reaches 180 camera heights; the columns' own offsets lower a row's rays a little)
    half = np.tan(np.radians(15.0))
    offset = np.degrees(np.arctan(((np.arange(33) + 0.5) / 33 * 2 - 1) * half))
    down = (90.0 - 82.0) + offset
    assert not img.mask[down <= 0.0].any() and img.mask[down > 1.0].all()
    assert (down <= 0.0).sum() >= 3
    assert not img.radiance[~img.mask].any()
    # a Lambertian plane under a directional light is uniform: rho / pi cos(theta_i) E
    flat = render_plane(registry.get("lambert").build(rho=0.8), 33, light_zenith_deg=60.0)
    np.testing.assert_allclose(flat.radiance[flat.mask], 0.4, rtol=1e-12)
    assert not render_plane(registry.get("lambert").build(rho=0.0), 9).radiance.any()


def test_new_parameter_values_compile_nothing():
    entry = registry.get("ggx")
    render_sphere(entry.build(alpha=0.3, f0=0.5), 17)
    with counting_compiles() as seen:
        render_sphere(entry.build(alpha=0.1, f0=0.9), 17, light_zenith_deg=60.0)
    assert seen == []
    with counting_compiles() as seen:  # the negative control: another size compiles
        render_sphere(entry.build(alpha=0.1, f0=0.9), 19)
    assert len(seen) >= 1


def test_srgb_encoding():
    v = np.array([[[0.0, 0.002, 0.5]], [[1.0, 2.0, 0.25]]])
    want = np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.clip(v, 0, 1) ** (1 / 2.4) - 0.055)
    np.testing.assert_array_equal(srgb_8bit(v), np.round(np.clip(want, 0, 1) * 255))
    np.testing.assert_array_equal(srgb_8bit(v * 0.5, exposure=1.0), srgb_8bit(v))


def test_command(tmp_path, capsys):
    png = tmp_path / "s.png"
    assert main(["render", "ggx", "--param", "alpha=0.3", "-o", str(png), "--size", "21",
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["out"] == str(png) and doc["size"] == 21 and doc["model"] == "ggx"
    assert matplotlib.image.imread(png).shape[:2] == (21, 21)
    # a fit's JSON gives the model and its parameters
    fitted = tmp_path / "fit.json"
    fitted.write_text(json.dumps({"model": "lambert", "params": {"rho": [0.2, 0.4, 0.6]}}))
    exr = tmp_path / "s.exr"
    pytest.importorskip("OpenEXR", reason="the OpenEXR bindings are not installed")
    assert main(["render", "--fit", str(fitted), "-o", str(exr), "--size", "21",
                 "--light-zenith-deg", "0", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    np.testing.assert_allclose(doc["radiance_max"], [0.2, 0.4, 0.6], rtol=1e-3)
    from brdf_fit.io.exr import read_exr

    pixels, channels, _ = read_exr(exr)
    assert channels == ("R", "G", "B", "A") and pixels.shape == (21, 21, 4)
    np.testing.assert_allclose(pixels[10, 10, :3], [0.2, 0.4, 0.6], rtol=1e-6)


def test_command_plane(tmp_path, capsys):
    png = tmp_path / "p.png"
    assert main(["render", "lambert", "--param", "rho=0.8", "--scene", "plane", "-o", str(png),
                 "--size", "21", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["scene"] == "plane" and doc["view_zenith_deg"] == 80.0
    # the default light is at the view's zenith on the far side: the glint at the centre
    assert doc["light"]["zenith_deg"] == 80.0 and doc["light"]["azimuth_deg"] == 90.0
    np.testing.assert_allclose(doc["radiance_max"], 0.8 * np.cos(np.radians(80.0)), rtol=1e-9)
    assert matplotlib.image.imread(png).shape[:2] == (21, 21)


@pytest.mark.parametrize("argv, fragment", [
    (["render", "-o", "X.png"], "needs a MODEL"),
    (["render", "--param", "alpha=0.1", "--data", "D.binary", "-o", "X.png"], "needs a MODEL"),
    (["render", "ggx", "-o", "X.jpg"], "expects .png or .exr"),
    (["render", "ggx", "-o", "X.png", "--light-zenith-deg", "95"], "must be in [0, 90)"),
    (["render", "nosuch", "-o", "X.png"], "nosuch"),
    (["render", "ggx", "--irradiance", "abc", "-o", "X.png"], "not a number"),
    (["render", "ggx", "--irradiance", "1,-2,3", "-o", "X.png"], "finite and >= 0"),
    (["render", "ggx", "--irradiance", "1,2", "-o", "X.png"], "one value or 3"),
    (["render", "ggx", "--fit", "F.json", "-o", "X.png"], "no MODEL or --param"),
    (["render", "ggx", "-o", "X.png", "--scene", "plane", "--environment", "1"],
     "the plane renders under the directional light"),
    (["render", "ggx", "-o", "X.png", "--view-zenith-deg", "60"], "with --scene plane"),
    (["render", "ggx", "-o", "X.png", "--scene", "plane", "--view-zenith-deg", "90"],
     "must be in (0, 90)"),
])
def test_command_errors(tmp_path, capsys, monkeypatch, argv, fragment):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and err[0].startswith("brdf-fit: error:") and fragment in err[0], err
    assert not (tmp_path / "X.png").exists()


# ----------------------------------------------------------------------------- data beside fit

CONDUCTOR = {"alpha": 0.3}


@pytest.fixture(scope="module")
def conductor_file(tmp_path_factory):
    """A MERL file made from ggx-conductor (its bin centres, write_merl)."""
    from brdf_fit.io.merl import write_merl

    path = tmp_path_factory.mktemp("merl") / "conductor.binary"
    write_merl(path, registry.get("ggx-conductor").build(**CONDUCTOR))
    return path


def test_flip_of_an_image_with_itself_is_zero():
    pytest.importorskip("flip_evaluator", reason="flip-evaluator is not installed")
    from brdf_fit.render import flip_error

    img = render_sphere(registry.get("ggx").build(alpha=0.2), 64)
    emap, mean = flip_error(img, img)
    assert mean == 0.0 and not emap.any()


def test_data_beside_its_model_and_a_model_that_misses(conductor_file):
    """Issue 46: the data's own sphere against the model that made them, FLIP mean < 0.01
    (0.0046 measured at 256 pixels: what is left is the interpolation between bins); a model
    that misses (Blinn-Phong on the rough metal) is far from it."""
    pytest.importorskip("flip_evaluator", reason="flip-evaluator is not installed")
    from brdf_fit.io.merl import read_merl_table
    from brdf_fit.render import MerlTable, flip_error

    data = render_sphere(MerlTable(read_merl_table(conductor_file)), 96)
    fit = render_sphere(registry.get("ggx-conductor").build(**CONDUCTOR), 96)
    miss = render_sphere(registry.get("blinn-phong").build(), 96)
    np.testing.assert_array_equal(data.mask, fit.mask)
    assert flip_error(data, fit)[1] < 0.01
    assert flip_error(data, miss)[1] > 0.1


def test_command_with_data(conductor_file, tmp_path, capsys):
    pytest.importorskip("flip_evaluator", reason="flip-evaluator is not installed")
    fitted = tmp_path / "fit.json"
    fitted.write_text(json.dumps({"model": "ggx-conductor", "params": CONDUCTOR}))
    out = tmp_path / "c.png"
    assert main(["render", "--fit", str(fitted), "--data", str(conductor_file), "-o", str(out),
                 "--size", "64", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["flip_mean"] < 0.01
    for key, name in (("out", "c.png"), ("data_out", "c_data.png"), ("flip_out", "c_flip.png")):
        assert doc[key] == str(tmp_path / name)
        assert matplotlib.image.imread(tmp_path / name).shape[:2] == (64, 64)
    # sparse data cannot be rendered from themselves
    csv = tmp_path / "s.csv"
    csv.write_text("theta_i,phi_i,theta_o,phi_o,value\n0,0,10,0,0.3\n")
    assert main(["render", "--data", str(csv), "-o", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert "dense data only" in err and not (tmp_path / "x.png").exists()


# ----------------------------------------------------------------------------- environment

def _albedo_z(model, img):
    """``(est - exact) / stderr`` per pixel and channel, the exact value the directional albedo
    by quadrature (brdf_fit.verify.albedo) at each pixel's view direction in its frame,
    ``(0, sin theta, cos theta)`` (the azimuthal tangent is orthogonal to the camera)."""
    from brdf_fit.verify.albedo import directional_albedo

    cv = img.cos_view[img.mask]
    wo = np.stack([np.zeros_like(cv), np.sqrt(1.0 - cv * cv), cv], -1)
    exact = np.asarray(directional_albedo(model, wo)).reshape(len(cv), -1)
    est = img.radiance[img.mask][:, :exact.shape[1]]
    se = img.stderr[img.mask][:, :exact.shape[1]]
    return (est - exact) / se


@pytest.mark.parametrize("name, params, heuristic", [
    ("lambert", {"rho": 0.8}, "balance"),
    ("ggx", {"alpha": 0.2, "f0": np.array([0.9, 0.6, 0.3])}, "balance"),
    ("ggx", {"alpha": 0.2, "f0": np.array([0.9, 0.6, 0.3])}, "power"),
])
def test_environment_estimate_is_the_albedo_within_its_stated_noise(name, params, heuristic):
    """Under a constant environment of radiance 1 a pixel is the directional albedo at its view
    (the white furnace); the estimate's stated standard errors are honest: z has mean ~0 and
    rms ~1, and 99% lie within 4 (measured: rms 1.01-1.04 at 64 samples per pixel)."""
    from brdf_fit.render import render_sphere_environment

    model = registry.get(name).build(**params)
    img = render_sphere_environment(model, 32, samples_per_pixel=64, heuristic=heuristic)
    z = _albedo_z(model, img)
    assert abs(z.mean()) < 0.15 and 0.85 < np.sqrt(np.mean(z * z)) < 1.2, (z.mean(), z.std())
    assert np.mean(np.abs(z) < 4) > 0.99
    assert not img.radiance[~img.mask].any() and img.samples_per_pixel == 64


def test_environment_compiles_once_and_refuses_a_delta_lobe():
    from brdf_fit.render import render_sphere_environment

    entry = registry.get("ggx")
    render_sphere_environment(entry.build(alpha=0.3), 16, samples_per_pixel=8)
    with counting_compiles() as seen:
        render_sphere_environment(entry.build(alpha=0.1, f0=np.array([0.9, 0.6, 0.3])), 16,
                                  samples_per_pixel=8, seed=3)
    assert seen == []
    with pytest.raises(ValueError, match="delta"):
        render_sphere_environment(registry.get("mirror").build(), 16)


def _mitsuba_environment_scene(mi, bsdf: dict, emitter: dict, size: int):
    """The sphere lit by ``emitter`` in Mitsuba 3: its ``direct`` integrator (emitter and BSDF
    samples, MIS), jittered samples over each pixel's area (box filter)."""
    T = mi.ScalarTransform4f
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "direct"},
        "sensor": {"type": "orthographic",
                   "to_world": T().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0])
                   @ T().scale([FRAME_HALF_WIDTH, FRAME_HALF_WIDTH, 1]),
                   "film": {"type": "hdrfilm", "width": size, "height": size,
                            "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent"}},
        "sphere": {"type": "sphere", "bsdf": bsdf},
        "light": emitter})


def _ours_over_mitsuba_pixels(big, size: int):
    """``(radiance, stderr, inner)`` of our render at 4 x 4 sub-pixels of each of Mitsuba's
    ``size`` x ``size`` pixels (it averages a pixel's area), averaged; ``inner``: the pixels
    wholly on the sphere and away from its rim."""
    ours = big.radiance[..., :3].reshape(size, 4, size, 4, 3).mean((1, 3))
    se = np.sqrt((big.stderr[..., :3] ** 2).reshape(size, 4, size, 4, 3).sum((1, 3))) / 16
    c = ((np.arange(size) + 0.5) / size * 2 - 1) * FRAME_HALF_WIDTH
    inner = big.mask.reshape(size, 4, size, 4).all((1, 3)) & (
        1 - c[None, :] ** 2 - c[:, None] ** 2 > 0.04)
    return ours, se, inner


@pytest.mark.slow
def test_environment_matches_mitsuba_within_noise():
    """Mitsuba 3 renders the same sphere under its ``constant`` emitter with its ``direct``
    integrator (emitter and BSDF samples, MIS), 1024 jittered samples per pixel, twice with two
    seeds (the pair's difference gives its noise). Mitsuba averages each pixel's area, so ours
    is rendered at 4 x 4 sub-pixels (16 samples each) and averaged; away from the rim the two
    agree within the combined noise (rms z 0.98-1.00 measured, bound 0.8-1.25)."""
    mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (the test extra)")
    from brdf_fit.convert.mitsuba import VARIANT, to_mitsuba
    from brdf_fit.render import render_sphere_environment

    mi.set_variant(VARIANT)
    size = 24
    for name in ("mitsuba-roughconductor", "mitsuba-roughplastic"):
        params = {"alpha": 0.2}
        scene = _mitsuba_environment_scene(
            mi, to_mitsuba(name, params, verify=False).scene_dict,
            {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}}, size)
        r1 = np.asarray(mi.render(scene, spp=1024, seed=1))[..., :3]
        r2 = np.asarray(mi.render(scene, spp=1024, seed=2))[..., :3]
        ours, se, inner = _ours_over_mitsuba_pixels(
            render_sphere_environment(registry.get(name).build(**params), 4 * size,
                                      samples_per_pixel=16), size)
        mitsuba_var = np.mean(((r1 - r2)[inner] / 2) ** 2)  # of the pair's mean, pooled
        z = (ours - 0.5 * (r1 + r2))[inner] / np.sqrt(se[inner] ** 2 + mitsuba_var)
        assert 0.8 < np.sqrt(np.mean(z * z)) < 1.25 and abs(z.mean()) < 0.2, (name, z.mean(),
                                                                               z.std())
        assert np.mean(np.abs(z) < 4) > 0.99, name


def _latlong_texels():
    """A 9 x 16 lat-long map: noise between 0.2 and 1 and a patch 20 times brighter (a small
    light, so that drawing from the map matters)."""
    tex = np.random.default_rng(1).uniform(0.2, 1.0, (9, 16, 3))
    tex[2:4, 5:7] *= 20.0
    return tex


def test_latlong_map_is_mitsubas_and_its_sampler_its_density():
    """The map's radiance is Mitsuba 3's ``envmap`` at 300 random directions (float32 texels
    there: 1e-5), where it is installed; its sampler draws unit directions whose density is the
    one :meth:`pdf` gives, ``E[1/pdf] = 4 pi`` and ``E[L/pdf]`` the integral of the map that
    uniform directions give, each within 4 standard errors."""
    import jax.numpy as jnp

    from brdf_fit.envmap import LatLongEnvironment

    tex = _latlong_texels()
    env = LatLongEnvironment.of(tex)
    rng = np.random.default_rng(2)
    d = rng.normal(size=(300, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ours = np.asarray(env.radiance(jnp.asarray(d)))
    try:
        import mitsuba as mi
    except ImportError:
        mi = None
    if mi is not None:
        mi.set_variant("scalar_rgb")
        em = mi.load_dict({"type": "envmap", "bitmap": mi.Bitmap(tex.astype(np.float32))})

        def at(x):
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*(-x))  # toward the point, as a camera ray seeing the map
            v = em.eval(si)
            return [v[0], v[1], v[2]]

        ref = np.array([at(x) for x in d])
        np.testing.assert_allclose(ours, ref, rtol=1e-5)
    u = jnp.asarray(rng.uniform(size=(200_000, 2)))
    ds, p = (np.asarray(a) for a in env.sample(u))
    np.testing.assert_allclose(np.linalg.norm(ds, axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(env.pdf(jnp.asarray(ds))), p, rtol=1e-6)
    inv = 1.0 / p
    assert abs(inv.mean() - 4 * np.pi) < 4 * inv.std() / np.sqrt(inv.size)
    L = np.asarray(env.radiance(jnp.asarray(ds)))[:, 0]
    z = rng.uniform(-1.0, 1.0, 400_000)
    phi = rng.uniform(0.0, 2 * np.pi, z.size)
    r = np.sqrt(1.0 - z * z)
    uni = 4 * np.pi * np.asarray(env.radiance(jnp.asarray(
        np.stack([r * np.cos(phi), r * np.sin(phi), z], -1))))[:, 0]
    se = np.hypot((L * inv).std() / np.sqrt(L.size), uni.std() / np.sqrt(uni.size))
    assert abs((L * inv).mean() - uni.mean()) < 4 * se
    with pytest.raises(ValueError, match="black everywhere"):
        LatLongEnvironment.of(np.zeros((4, 8, 3)))
    with pytest.raises(ValueError, match="finite and >= 0"):
        LatLongEnvironment.of(-tex)


def test_latlong_environment_matches_mitsuba_within_noise():
    """The sphere under the lat-long map, against Mitsuba 3's ``direct`` integrator with its
    ``envmap`` emitter of the same texels (as the constant environment's test: 1024 jittered
    samples twice, ours at 4 x 4 sub-pixels averaged, compared within the combined noise)."""
    mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (the test extra)")
    from brdf_fit.convert.mitsuba import VARIANT, to_mitsuba
    from brdf_fit.envmap import LatLongEnvironment
    from brdf_fit.render import render_sphere_environment

    mi.set_variant(VARIANT)
    size = 24
    tex = _latlong_texels()
    name, params = "mitsuba-roughconductor", {"alpha": 0.3}
    scene = _mitsuba_environment_scene(
        mi, to_mitsuba(name, params, verify=False).scene_dict,
        {"type": "envmap", "bitmap": mi.Bitmap(tex.astype(np.float32))}, size)
    runs = np.stack([np.asarray(mi.render(scene, spp=1024, seed=k))[..., :3]
                     for k in range(1, 5)])
    ours, se, inner = _ours_over_mitsuba_pixels(
        render_sphere_environment(registry.get(name).build(**params), 4 * size,
                                  samples_per_pixel=16, environment=LatLongEnvironment.of(tex)),
        size)
    # the map's bright patch makes the noise differ from pixel to pixel: Mitsuba's own, of
    # the four runs' mean, per pixel from their spread
    mitsuba_var = runs.var(0, ddof=1) / len(runs)
    z = (ours - runs.mean(0))[inner] / np.sqrt(se[inner] ** 2 + mitsuba_var[inner])
    assert 0.8 < np.sqrt(np.mean(z * z)) < 1.25 and abs(z.mean()) < 0.2, (z.mean(), z.std())
    assert np.mean(np.abs(z) < 4) > 0.99


def test_command_environment(tmp_path, capsys):
    out = tmp_path / "e.png"
    assert main(["render", "lambert", "--param", "rho=0.5", "--environment", "2", "--spp", "16",
                 "--size", "16", "-o", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["light"] is None and doc["environment"]["samples_per_pixel"] == 16
    np.testing.assert_allclose(doc["radiance_mean"], [1.0, 1.0, 1.0], rtol=0.02)  # 2 x 0.5
    assert 0 < doc["environment"]["stderr_relative_median"] < 0.2
    assert main(["render", "mirror", "--environment", "1", "-o", str(out)]) == 2
    assert "delta lobe" in capsys.readouterr().err


def test_command_environment_map(tmp_path, capsys):
    """``--environment-map FILE.exr``: a Lambertian sphere under a map of one value everywhere
    renders that value times its albedo (the map's scale by --environment); errors name the
    option and the file."""
    pytest.importorskip("OpenEXR", reason="the OpenEXR bindings are not installed")
    from brdf_fit.io.exr import write_exr

    flat = tmp_path / "flat.exr"
    write_exr(flat, np.full((8, 16, 3), 2.0, np.float32), channels=("R", "G", "B"))
    out = tmp_path / "m.png"
    assert main(["render", "lambert", "--param", "rho=0.5", "--environment-map", str(flat),
                 "--environment", "0.5", "--spp", "16", "--size", "16", "-o", str(out),
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["environment"]["map"] == str(flat) and doc["environment"]["map_shape"] == [8, 16]
    np.testing.assert_allclose(doc["radiance_mean"], [0.5, 0.5, 0.5], rtol=0.02)  # .5 2 .5
    # the package's procedural sky, by name
    assert main(["render", "lambert", "--param", "rho=0.5", "--environment-map", "sky",
                 "--spp", "16", "--size", "16", "-o", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["environment"]["map"] == "sky" and doc["environment"]["map_shape"] == [64, 128]
    for argv, fragment in (
            (["--environment-map", str(tmp_path / "none.exr")], "no such file"),
            (["--environment-map", str(flat), "--scene", "plane"], "directional light"),
            (["--environment-map", str(out)], "--environment-map")):
        assert main(["render", "ggx", "-o", str(tmp_path / "x.png"), *argv]) == 2
        err = capsys.readouterr().err
        assert fragment in err and err.count("\n") == 1, err


# ----------------------------------------------------------------------------- RGL data


@pytest.fixture(scope="module")
def rgl_file(tmp_path_factory):
    """An isotropic RGL ``.bsdf`` material with random tables (tests/io/test_rgl.py's)."""
    from brdf_fit.io.rgl import write_tensor_file
    from tests.io.test_rgl import _material_fields

    path = tmp_path_factory.mktemp("rgl") / "iso.bsdf"
    write_tensor_file(path, **_material_fields("iso", seed=44))
    return path


def test_rgl_data_render_from_themselves_and_give_their_slice(rgl_file, tmp_path, capsys):
    """An RGL file renders through its own evaluation (Mitsuba's measured plugin's, checked
    in tests/io/test_rgl.py): every sphere pixel is the material at that pixel's pair times
    the light's cosine and irradiance; beside a model the command gives FLIP; its Rusinkiewicz
    slice is the material at the slice's bin centres; a sparse file is refused."""
    from brdf_fit.io.merl import merl_slice_centres
    from brdf_fit.io.rgl import RGLMaterial, read_tensor_file
    from brdf_fit.plot import rusinkiewicz_slices
    from brdf_fit.render import dense_data, sphere_geometry

    shader = dense_data(rgl_file)
    img = render_sphere(shader, 33, light_zenith_deg=40.0)
    material = RGLMaterial(read_tensor_file(rgl_file))
    wi, wo, cos_i, m, _ = sphere_geometry(33, img.light)
    want = material.eval(wi, wo) * cos_i[:, None] * IRRADIANCE
    np.testing.assert_allclose(img.radiance.reshape(-1, 3)[m], want[m], rtol=1e-12)
    assert img.radiance.reshape(-1, 3)[m].max() > 0
    _, _, data, _ = rusinkiewicz_slices(shader, [])
    swi, swo, _, _ = merl_slice_centres(90)  # the bin holding phi_d = 90 degrees
    want = material.eval(swi.reshape(-1, 3), swo.reshape(-1, 3))[:, 1].reshape(data.shape)
    ok = (swi[..., 2] > 0) & (swo[..., 2] > 0)
    np.testing.assert_allclose(data[ok], want[ok], rtol=1e-12)
    assert np.isnan(data[~ok]).all()
    out = tmp_path / "r.png"
    pytest.importorskip("flip_evaluator", reason="NVIDIA's FLIP (flip-evaluator) is not installed")
    assert main(["render", "lambert", "--data", str(rgl_file), "--size", "24", "-o", str(out),
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["data"] == str(rgl_file) and doc["flip_mean"] > 0
    assert (tmp_path / "r_data.png").exists() and (tmp_path / "r_flip.png").exists()
    csv = tmp_path / "sparse.csv"
    csv.write_text("theta_i,phi_i,theta_o,phi_o,value\n10,0,10,180,0.5\n")
    assert main(["render", "--data", str(csv), "-o", str(out)]) == 2
    assert "dense data only" in capsys.readouterr().err
