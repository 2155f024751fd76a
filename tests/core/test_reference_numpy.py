"""Self-checks of the independent NumPy reference (``reference_numpy.py``).

These tests check the reference implementation itself -- against closed-form identities
of the microfacet theory, numerical quadrature, independent real-arithmetic Fresnel
formulae and published reference values -- without importing ``brdf_fit``.
"""

from __future__ import annotations

import numpy as np
import pytest
from reference_numpy import (
    angles,
    direction,
    ref_D,
    ref_fresnel_conductor,
    ref_fresnel_conductor_polarized,
    ref_fresnel_dielectric,
    ref_fresnel_schlick,
    ref_G1,
    ref_G2,
    ref_lambda,
    ref_microfacet_eval,
)

try:
    from scipy.integrate import cubature  # scipy >= 1.15
except ImportError:  # pragma: no cover
    cubature = None

needs_cubature = pytest.mark.skipif(
    cubature is None, reason="scipy.integrate.cubature needs scipy >= 1.15"
)

DISTS = ["ggx", "beckmann"]
ROUGHNESS = [(0.3, 0.3), (0.1, 0.5), (0.8, 0.4)]
TWO_PI = 2.0 * np.pi


# ----------------------------------------------------------------------------------------
# Normalisation of D:  integral D(m) cos(theta_m) d omega_m = 1   ([Heitz14])
# ----------------------------------------------------------------------------------------


def _projected_area(dist, ax, ay):
    """integral over the hemisphere of D(m) cos(theta_m) d omega_m.

    Change of variables adapted to the peak: for each azimuth phi the polar angle is
    parametrised as tan(theta) = beta(phi) t, beta = (cos^2/ax^2 + sin^2/ay^2)^(-1/2), and
    t = v / (1 - v) maps [0, 1) onto [0, inf). d omega = sin(theta) d theta d phi.
    """

    def integrand(x):
        v, phi = x[:, 0], x[:, 1]
        beta = 1.0 / np.sqrt(np.cos(phi) ** 2 / ax**2 + np.sin(phi) ** 2 / ay**2)
        t = v / (1.0 - v)
        dt_dv = 1.0 / (1.0 - v) ** 2
        theta = np.arctan(beta * t)
        dtheta_dt = beta / (1.0 + (beta * t) ** 2)
        d = ref_D(direction(theta, phi), dist, ax, ay)
        return d * np.cos(theta) * np.sin(theta) * dtheta_dt * dt_dv

    res = cubature(integrand, [0.0, 0.0], [1.0, TWO_PI], rtol=1e-10, atol=1e-13)
    assert res.status == "converged"
    return float(res.estimate)


@needs_cubature
@pytest.mark.parametrize("dist", DISTS)
@pytest.mark.parametrize(("ax", "ay"), ROUGHNESS)
def test_D_projected_area_is_one(dist, ax, ay):
    assert abs(_projected_area(dist, ax, ay) - 1.0) < 1e-6


# ----------------------------------------------------------------------------------------
# Masking normalisation ("weak white furnace"; projected visible area, [Heitz14]):
#   G1(wo) integral max(0, wo.m) D(m) d omega_m = cos(theta_o)
# ----------------------------------------------------------------------------------------


def _projected_visible_area(dist, ax, ay, theta_o, phi_o):
    """integral max(0, wo.m) D(m) d omega_m, integrated only where wo.m > 0.

    tan(theta_m) = beta0 t. For theta_m <= pi/2 - theta_o every azimuth has wo.m > 0
    (region 1, t in [0, t*]); beyond it wo.m > 0 iff |phi - phi_o| < Phi(theta_m) with
    cos(Phi) = -cot(theta_o) cot(theta_m) (region 2, phi = phi_o + Phi s, s in [-1, 1],
    t = t* + q^2 to remove the square-root behaviour of Phi at t*, q = w / (1 - w)).
    Within both regions the integrand is smooth.
    """
    wo = direction(theta_o, phi_o)
    beta0 = min(ax, ay)
    t_star = 1.0 / (np.tan(theta_o) * beta0)

    def visible(theta, phi):
        m = direction(theta, phi)
        return ref_D(m, dist, ax, ay) * np.maximum(m @ wo, 0.0) * np.sin(theta)

    def region1(x):
        t, phi = x[:, 0], x[:, 1]
        theta = np.arctan(beta0 * t)
        return visible(theta, phi) * beta0 / (1.0 + (beta0 * t) ** 2)

    def region2(x):
        w, s = x[:, 0], x[:, 1]
        q = w / (1.0 - w)
        t = t_star + q * q
        dt_dw = 2.0 * q / (1.0 - w) ** 2
        theta = np.arctan(beta0 * t)
        dtheta_dt = beta0 / (1.0 + (beta0 * t) ** 2)
        half_width = np.arccos(np.clip(-1.0 / (np.tan(theta_o) * np.tan(theta)), -1.0, 1.0))
        phi = phi_o + half_width * s
        return visible(theta, phi) * dtheta_dt * dt_dw * half_width

    tol = {"rtol": 1e-10, "atol": 1e-13}
    r1 = cubature(region1, [0.0, 0.0], [t_star, TWO_PI], **tol)
    r2 = cubature(region2, [0.0, -1.0], [1.0, 1.0], **tol)
    assert r1.status == "converged" and r2.status == "converged"
    return float(r1.estimate + r2.estimate)


@needs_cubature
@pytest.mark.parametrize("dist", DISTS)
@pytest.mark.parametrize(("ax", "ay"), ROUGHNESS)
@pytest.mark.parametrize("theta_o", [0.3, 1.2, 1.5])
def test_masking_weak_white_furnace(dist, ax, ay, theta_o):
    phi_o = 0.7  # not aligned with an anisotropy axis
    wo = direction(theta_o, phi_o)[None]
    area = _projected_visible_area(dist, ax, ay, theta_o, phi_o)
    g1 = ref_G1(wo, dist, ax, ay)[0]
    assert abs(g1 * area - np.cos(theta_o)) < 1e-5
    # equivalently, Lambda(wo) = area / cos(theta_o) - 1 (Smith: G1 = 1 / (1 + Lambda))
    lam = ref_lambda(wo, dist, ax, ay)[0]
    assert lam == pytest.approx(area / np.cos(theta_o) - 1.0, rel=1e-6, abs=1e-9)


# ----------------------------------------------------------------------------------------
# D: literature / Mitsuba 3 reference values and axis convention
# ----------------------------------------------------------------------------------------

# Values from Mitsuba 3, src/render/tests/test_microfacet.py (test02_eval_pdf_beckmann),
# computed in single precision: Beckmann, (alpha_u, alpha_v) = (0.1, 0.3) and 0.1.
_MI_BECKMANN_THETA_SWEEP_ANISO = [
    1.06103287e01, 8.22650051e00, 3.57923722e00, 6.84863329e-01, 3.26460004e-02,
    1.01964230e-04, 5.87322635e-10,
]  # fmt: skip
_MI_BECKMANN_THETA_SWEEP_ISO = [3.18309879e01, 2.07673073e00, 3.02855828e-04, 1.01591990e-11]
_MI_BECKMANN_PHI_SWEEP_ANISO = [
    3.95569706, 4.34706259, 5.54415846, 7.4061389, 9.17129803, 9.62056446, 8.37803268,
    6.42071199, 4.84459257, 4.05276537, 4.05276537, 4.84459257, 6.42071199, 8.37803268,
    9.62056446, 9.17129803, 7.4061389, 5.54415846, 4.34706259, 3.95569706,
]  # fmt: skip


def test_D_reference_values():
    n = np.array([[0.0, 0.0, 1.0]])
    assert ref_D(n, "beckmann", 0.1, 0.3)[0] == pytest.approx(10.6103287, rel=1e-6)
    assert ref_D(n, "beckmann", 0.1, 0.1)[0] == pytest.approx(31.8309879, rel=1e-6)
    assert ref_D(n, "ggx", 0.1, 0.1)[0] == pytest.approx(31.8309879, rel=1e-6)
    # exact: 1 / (pi ax ay) at the normal
    assert ref_D(n, "ggx", 0.2, 0.7)[0] == pytest.approx(1.0 / (np.pi * 0.14), rel=1e-14)

    phi = np.linspace(0.0, TWO_PI, 20)
    d_iso = ref_D(direction(0.1, phi), "beckmann", 0.1, 0.1)
    np.testing.assert_allclose(d_iso, 11.86709118, rtol=1e-6)
    d_aniso = ref_D(direction(0.1, phi), "beckmann", 0.1, 0.3)
    np.testing.assert_allclose(d_aniso, _MI_BECKMANN_PHI_SWEEP_ANISO, rtol=1e-6)

    theta = np.linspace(0.0, np.pi, 20)
    d = ref_D(direction(theta, np.pi / 2), "beckmann", 0.1, 0.3)
    np.testing.assert_allclose(d[:7], _MI_BECKMANN_THETA_SWEEP_ANISO, rtol=1e-5)
    assert np.all(d[7:] < 1e-20)
    d = ref_D(direction(theta, np.pi / 2), "beckmann", 0.1, 0.1)
    np.testing.assert_allclose(d[:4], _MI_BECKMANN_THETA_SWEEP_ISO, rtol=1e-5)
    assert np.all(d[np.cos(theta) <= 0.0] == 0.0)


@pytest.mark.parametrize("dist", DISTS)
def test_D_matches_slope_space_form_and_axis_convention(dist):
    """D(m) = P22(x~, y~) / cos^4(theta_m) with slopes x~ = -m_x/m_z, y~ = -m_y/m_z
    ([Heitz14], slope-space form), written here in Cartesian form; alpha_x is the width along x."""
    rng = np.random.default_rng(1)
    m = rng.normal(size=(200, 3))
    m[:, 2] = np.abs(m[:, 2]) + 0.05
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    ax, ay = 0.25, 0.6
    r2 = (m[:, 0] / (m[:, 2] * ax)) ** 2 + (m[:, 1] / (m[:, 2] * ay)) ** 2
    if dist == "ggx":
        p22 = 1.0 / (np.pi * ax * ay * (1.0 + r2) ** 2)
    else:
        p22 = np.exp(-r2) / (np.pi * ax * ay)
    # Beckmann: exp(-r2) amplifies rounding of its argument (condition number r2 ~ 600)
    np.testing.assert_allclose(ref_D(m, dist, ax, ay), p22 / m[:, 2] ** 4, rtol=1e-10)
    # wider along the axis with the larger roughness
    tilt_x, tilt_y = direction(0.4, 0.0), direction(0.4, np.pi / 2)
    assert ref_D(tilt_x, dist, 0.5, 0.1) > ref_D(tilt_y, dist, 0.5, 0.1)
    assert ref_D(m * 3.7, dist, ax, ay) == pytest.approx(ref_D(m, dist, ax, ay), rel=1e-14)
    assert np.all(ref_D(-m, dist, ax, ay) == 0.0)


# ----------------------------------------------------------------------------------------
# Lambda / G1
# ----------------------------------------------------------------------------------------

# Mitsuba 3 test_microfacet.py (test03_smith_g1_*), single precision. Mitsuba's Beckmann
# smith_g1 uses the Walter 2007 rational approximation, its GGX smith_g1 is exact.
_MI_G1_BECKMANN_ANISO = [
    1.0, 1.0, 1.0, 1.0000523, 0.9994148, 0.99757767, 0.99420297, 0.98884594, 0.98091525,
    0.96961778, 0.95387781, 0.93222123, 0.90260512, 0.86216795, 0.8068614, 0.73091686,
    0.62609726, 0.48074335, 0.27883825, 1.9197471e-06,
]  # fmt: skip
_MI_G1_BECKMANN_PHI = [
    0.67333597, 0.56164336, 0.42798978, 0.35298213, 0.31838724, 0.31201753, 0.33166203,
    0.38421196, 0.48717275, 0.63746351, 0.63746351, 0.48717275, 0.38421196, 0.33166203,
    0.31201753, 0.31838724, 0.35298213, 0.42798978, 0.56164336, 0.67333597,
]  # fmt: skip
_MI_G1_GGX_ANISO = [
    0.94031686, 0.93310797, 0.92485082, 0.91534841, 0.90435863, 0.89158219, 0.8766489,
    0.85909742, 0.83835226, 0.8136934, 0.78421932, 0.74880326, 0.70604056, 0.65419233,
    0.59112519, 0.51425743, 0.42051861, 0.30633566, 0.16765384, 1.0861372e-06,
]  # fmt: skip
_MI_G1_GGX_ISO = [
    0.99261039, 0.99160647, 0.99042398, 0.98901933, 0.98733366, 0.98528832, 0.98277503,
    0.97964239, 0.97567332, 0.97054905, 0.9637875, 0.95463598, 0.94187391, 0.92344058,
    0.8956942, 0.85189372, 0.77902949, 0.65144652, 0.41989169, 3.2584082e-06,
]  # fmt: skip
_MI_G1_GGX_PHI = [
    0.46130955, 0.36801264, 0.26822716, 0.21645154, 0.19341162, 0.18922243, 0.20219423,
    0.23769052, 0.31108665, 0.43013984, 0.43013984, 0.31108665, 0.23769052, 0.20219423,
    0.18922243, 0.19341162, 0.21645154, 0.26822716, 0.36801264, 0.46130955,
]  # fmt: skip


def test_G1_mitsuba_reference_values():
    n = np.array([0.0, 0.0, 1.0])
    v = direction(np.linspace(np.pi / 3, np.pi / 2, 20), np.pi / 2)
    g = ref_G1(v, "beckmann", 0.1, 0.3, m=n, approx="walter")
    np.testing.assert_allclose(g, _MI_G1_BECKMANN_ANISO, atol=1e-5, rtol=0)
    g = ref_G1(v, "ggx", 0.1, 0.3, m=n)
    np.testing.assert_allclose(g, _MI_G1_GGX_ANISO, atol=1e-5, rtol=0)
    g = ref_G1(v, "ggx", 0.1, 0.1, m=n)
    np.testing.assert_allclose(g, _MI_G1_GGX_ISO, atol=1e-5, rtol=0)

    v = direction(np.pi / 2 * 0.98, np.linspace(0.0, TWO_PI, 20))
    g = ref_G1(v, "beckmann", 0.1, 0.3, m=n, approx="walter")
    np.testing.assert_allclose(g, _MI_G1_BECKMANN_PHI, rtol=1e-5)
    np.testing.assert_allclose(
        ref_G1(v, "beckmann", 0.1, 0.1, approx="walter"), 0.67333597, rtol=1e-5
    )
    np.testing.assert_allclose(ref_G1(v, "ggx", 0.1, 0.3, m=n), _MI_G1_GGX_PHI, rtol=1e-5)
    np.testing.assert_allclose(ref_G1(v, "ggx", 0.1, 0.1), 0.46130955, rtol=1e-5)


def test_lambda_closed_forms_and_limits():
    theta = np.linspace(0.0, 1.55, 50)
    phi = np.linspace(-3.0, 3.0, 50)
    w = direction(theta, phi)
    ax, ay = 0.2, 0.45
    alpha_o = np.sqrt(np.cos(phi) ** 2 * ax**2 + np.sin(phi) ** 2 * ay**2)
    # GGX: G1 = 2 / (1 + sqrt(1 + alpha^2 tan^2 theta))  ([Walter07] eq. 34)
    g_walter34 = 2.0 / (1.0 + np.sqrt(1.0 + (alpha_o * np.tan(theta)) ** 2))
    np.testing.assert_allclose(ref_G1(w, "ggx", ax, ay), g_walter34, rtol=1e-13)
    # Beckmann: Walter's rational approximation is within ~0.35% of the exact G1 (Walter07)
    g_exact = ref_G1(w, "beckmann", ax, ay)
    g_approx = ref_G1(w, "beckmann", ax, ay, approx="walter")
    assert np.max(np.abs(g_approx / g_exact - 1.0)) < 4e-3
    # limits: Lambda(n) = 0, Lambda(horizon) = inf, Lambda >= 0 and increasing with theta
    for dist in DISTS:
        lam = ref_lambda(direction(theta, 0.3), dist, ax, ay)
        assert lam[0] == 0.0 and np.all(np.diff(lam) >= 0.0)
        assert np.isinf(ref_lambda(np.array([1.0, 0.0, 0.0]), dist, ax, ay))
        assert ref_G1(np.array([1.0, 0.0, 0.0]), dist, ax, ay) == 0.0
        assert ref_G1(np.array([0.3, 0.0, -1.0]), dist, ax, ay) == 0.0
        # Lambda(-w) = -1 - Lambda(w)
        lam_w = ref_lambda(w, dist, ax, ay)
        np.testing.assert_allclose(ref_lambda(-w, dist, ax, ay), -1.0 - lam_w, rtol=1e-12)
    # large a: Beckmann Lambda is positive and tiny, no catastrophic cancellation to < 0
    lam_small = ref_lambda(direction(np.array([1e-3, 0.02, 0.05]), 0.0), "beckmann", 0.1, 0.1)
    assert np.all(lam_small >= 0.0) and lam_small[2] < 1e-80


# ----------------------------------------------------------------------------------------
# Fresnel
# ----------------------------------------------------------------------------------------


def _snell_real(cos_i, n):
    """Real-arithmetic Fresnel (Born & Wolf) for a non-absorbing dielectric, n > 1."""
    sin_t = np.sqrt(1.0 - cos_i**2) / n
    cos_t = np.sqrt(1.0 - sin_t**2)
    rs = ((cos_i - n * cos_t) / (cos_i + n * cos_t)) ** 2
    rp = ((n * cos_i - cos_t) / (n * cos_i + cos_t)) ** 2
    return rs, rp


def _conductor_real(cos_i, n, k):
    """Exact conductor reflectance in real arithmetic (Born & Wolf Sec. 14.2 via the
    auxiliary quantities a^2 + b^2 and a)."""
    sin2 = 1.0 - cos_i**2
    t0 = n * n - k * k - sin2
    a2pb2 = np.sqrt(t0 * t0 + 4.0 * n * n * k * k)
    a = np.sqrt(0.5 * (a2pb2 + t0))
    rs = (a2pb2 + cos_i**2 - 2.0 * a * cos_i) / (a2pb2 + cos_i**2 + 2.0 * a * cos_i)
    t3 = cos_i**2 * a2pb2 + sin2 * sin2
    t4 = 2.0 * a * cos_i * sin2
    rp = rs * (t3 - t4) / (t3 + t4)
    return rs, rp


def test_fresnel_dielectric_values():
    assert ref_fresnel_conductor(1.0, 1.5, 0.0) == pytest.approx(0.04, rel=1e-14)
    c45 = np.cos(np.pi / 4)
    rs, rp = _snell_real(c45, 1.5)
    assert rs == pytest.approx(0.0920, abs=5e-5) and rp == pytest.approx(0.0085, abs=5e-5)
    f45 = ref_fresnel_conductor(c45, 1.5, 0.0)
    assert f45 == pytest.approx(0.5 * (rs + rp), rel=1e-13)
    assert f45 == pytest.approx(0.05024, abs=1e-5)
    # polarised components: r_par is p-polarised, r_perp is s-polarised
    r_par, r_perp = ref_fresnel_conductor_polarized(c45, 1.5, 0.0)
    assert r_par == pytest.approx(rp, rel=1e-12) and r_perp == pytest.approx(rs, rel=1e-12)
    # Brewster angle: R_p = 0
    c_b = np.cos(np.arctan(1.5))
    r_par, r_perp = ref_fresnel_conductor_polarized(c_b, 1.5, 0.0)
    assert r_par < 1e-30
    assert r_perp == pytest.approx(_snell_real(c_b, 1.5)[0], rel=1e-12)
    # grazing incidence -> 1
    c = np.array([1e-3, 1e-6, 1e-9, 0.0])
    f = ref_fresnel_conductor(c, 1.5, 0.0)
    assert np.all(np.diff(f) > 0.0) and f[-1] == pytest.approx(1.0, abs=1e-14)
    assert 1.0 - f[1] < 1e-5
    # sweep against the real Snell formula
    cs = np.linspace(0.01, 1.0, 100)
    np.testing.assert_allclose(
        ref_fresnel_dielectric(cs, 1.5), 0.5 * np.add(*_snell_real(cs, 1.5)), rtol=1e-12
    )
    # inside the denser medium: total internal reflection beyond the critical angle
    c_crit = np.cos(np.arcsin(1.0 / 1.5))
    assert np.all(ref_fresnel_dielectric(np.array([0.2, c_crit * 0.99]), 1 / 1.5) > 1 - 1e-12)


def test_fresnel_conductor_values():
    n, k = 0.2, 3.9
    f1 = ref_fresnel_conductor(1.0, n, k)
    assert f1 == pytest.approx(((n - 1) ** 2 + k**2) / ((n + 1) ** 2 + k**2), rel=1e-14)
    cs = np.linspace(0.0, 1.0, 101)
    for n, k in [(0.2, 3.9), (1.1, 2.0), (2.5, 0.3), (0.05, 1.5), (1.5, 0.0)]:
        rs, rp = _conductor_real(cs, n, k)
        r_par, r_perp = ref_fresnel_conductor_polarized(cs, n, k)
        np.testing.assert_allclose(r_perp, rs, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(r_par, rp, rtol=1e-11, atol=1e-15)
        np.testing.assert_allclose(ref_fresnel_conductor(cs, n, k), 0.5 * (rs + rp), rtol=1e-12)
        assert ref_fresnel_conductor(0.0, n, k) == pytest.approx(1.0, abs=1e-12)
    # channels: (N,) x (C,) -> (N, C), column j equals the scalar evaluation
    eta, kk = np.array([0.2, 1.1, 2.5]), np.array([3.9, 2.0, 0.3])
    fc = ref_fresnel_conductor(cs, eta, kk)
    assert fc.shape == (cs.size, 3)
    for j in range(3):
        np.testing.assert_allclose(fc[:, j], ref_fresnel_conductor(cs, eta[j], kk[j]), rtol=1e-15)


def test_fresnel_schlick():
    c = np.array([0.0, 0.3, 1.0])
    np.testing.assert_allclose(ref_fresnel_schlick(c, 0.04), 0.04 + 0.96 * (1 - c) ** 5)
    assert ref_fresnel_schlick(c, [0.1, 0.5]).shape == (3, 2)
    np.testing.assert_allclose(ref_fresnel_schlick(c, [0.1, 0.5])[:, 1], 0.5 + 0.5 * (1 - c) ** 5)


# ----------------------------------------------------------------------------------------
# Full BRDF: cross-check against an in-test Cartesian (dot-product) evaluation
# ----------------------------------------------------------------------------------------


def _cartesian_brdf(wi, wo, dist, ax, ay, g2, n, k):
    """Straightforward dot-product evaluation, used only to test the angle plumbing."""
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    ci, co, ch = wi[:, 2], wo[:, 2], h[:, 2]
    cdot = np.sum(wo * h, axis=-1)
    r2 = (h[:, 0] / ax) ** 2 + (h[:, 1] / ay) ** 2
    if dist == "ggx":
        d = 1.0 / (np.pi * ax * ay * (ch * ch + r2) ** 2)
    else:
        d = np.exp(-r2 / ch**2) / (np.pi * ax * ay * ch**4)

    def lam(w):
        s = np.sqrt((w[:, 0] * ax) ** 2 + (w[:, 1] * ay) ** 2)  # alpha_o sin(theta)
        if dist == "ggx":
            return 0.5 * (np.sqrt(1.0 + (s / w[:, 2]) ** 2) - 1.0)
        from scipy.special import erf

        a = w[:, 2] / s
        return 0.5 * (erf(a) - 1.0) + np.exp(-a * a) / (2.0 * a * np.sqrt(np.pi))

    li, lo = lam(wi), lam(wo)
    if g2 == "separable":
        g = 1.0 / ((1.0 + li) * (1.0 + lo))
    elif g2 == "height-correlated":
        g = 1.0 / (1.0 + li + lo)
    else:
        g = np.minimum(1.0, np.minimum(2 * ch * co / cdot, 2 * ch * ci / cdot))
    rs, rp = _conductor_real(cdot[:, None], np.asarray(n), np.asarray(k))
    f = 0.5 * (rs + rp)
    return f * (d * g / (4.0 * ci * co))[:, None]


@pytest.mark.parametrize("dist", DISTS)
@pytest.mark.parametrize("g2", ["separable", "height-correlated", "v-cavity"])
def test_microfacet_eval_matches_cartesian_form(dist, g2):
    rng = np.random.default_rng(7)
    wi = direction(rng.uniform(0.0, 1.45, 300), rng.uniform(-np.pi, np.pi, 300))
    wo = direction(rng.uniform(0.0, 1.45, 300), rng.uniform(-np.pi, np.pi, 300))
    eta, k = [0.2, 1.1, 1.5], [3.9, 2.0, 0.0]
    ax, ay = 0.35, 0.12
    f = ref_microfacet_eval(wi, wo, dist, ax, ay, g2, ("conductor", eta, k))
    assert f.shape == (300, 3)
    expected = _cartesian_brdf(wi, wo, dist, ax, ay, g2, eta, k)
    np.testing.assert_allclose(f, expected, rtol=1e-9, atol=1e-300)
    # reciprocity f(wi, wo) = f(wo, wi)
    f_swap = ref_microfacet_eval(wo, wi, dist, ax, ay, g2, ("conductor", eta, k))
    np.testing.assert_allclose(f_swap, f, rtol=1e-12, atol=1e-300)
    # G2 consistency with the standalone function
    g = ref_G2(wi, wo, dist, ax, ay, g2)
    assert np.all((g >= 0.0) & (g <= 1.0 + 1e-15))


def test_microfacet_eval_below_horizon_and_shapes():
    wi = direction(np.array([0.3, 1.7, 0.4, np.pi / 2]), 0.2)
    wo = direction(np.array([0.5, 0.5, 1.9, 0.5]), 2.0)
    for dist in DISTS:
        f = ref_microfacet_eval(wi, wo, dist, 0.3, 0.3, "height-correlated", ("schlick", 0.04))
        assert f.shape == (4,) and f[0] > 0.0 and np.all(f[1:] == 0.0)
    f = ref_microfacet_eval(wi, wo, "ggx", 0.3, None, "separable", ("schlick", [0.04, 0.9]))
    assert f.shape == (4, 2)
    # isotropic default and F = 1 option
    f1 = ref_microfacet_eval(wi[:1], wo[:1], "ggx", 0.3, fresnel=None)
    fs = ref_microfacet_eval(wi[:1], wo[:1], "ggx", 0.3, fresnel=("schlick", 1.0))
    np.testing.assert_allclose(f1, fs, rtol=1e-15)
    # specular configuration: h = n, so D(h) = 1 / (pi ax ay) and F(cos_o)
    wo_s = direction(0.6, 1.0)[None]
    wi_s = direction(0.6, 1.0 + np.pi)[None]
    th, _ = angles(wi_s + wo_s)
    assert th[0] < 1e-15
    f = ref_microfacet_eval(
        wi_s, wo_s, "beckmann", 0.2, 0.3, "height-correlated", ("conductor", 0.2, 3.9)
    )
    lam = ref_lambda(wo_s, "beckmann", 0.2, 0.3)[0]
    lam_i = ref_lambda(wi_s, "beckmann", 0.2, 0.3)[0]
    expected = (
        ref_fresnel_conductor(np.cos(0.6), 0.2, 3.9)
        / (np.pi * 0.06)
        / (1 + lam + lam_i)
        / (4 * np.cos(0.6) ** 2)
    )
    assert f[0] == pytest.approx(expected, rel=1e-12)
