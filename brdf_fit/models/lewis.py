"""Lewis's physically plausible (normalised) Phong BRDF (Lewis 1993/1994).

R. R. Lewis, "Making shaders more physically plausible", Fourth Eurographics Workshop on
Rendering, 1993, and Computer Graphics Forum 13(2):109-120, 1994; models.md 4.18::

    f = kd/pi + ks (n+2)/(2 pi) cos^n(alpha_r),     cos(alpha_r) = max(0, r_o.wi)
                                                    = max(0, 2 (n.wi)(n.wo) - wi.wo)

Source note: the primary paper could not be re-read here; the formula follows models.md 4.18,
which gives it as identical to Lafortune & Willems' (1994) modified Phong, and the ``(n+2)/(2 pi)``
normaliser agrees with Lafortune & Willems 1994 and F. Giesen, "Derivation of Phong and
Blinn-Phong BRDF normalization factors", 2009. Lewis also discusses a plausible Blinn
(half-vector) variant; it is not implemented here (see :class:`brdf_fit.models.phong.BlinnPhong`).

``(n+2)`` versus ``(n+1)``. ``(n+2)/(2 pi)`` normalises the *cosine-weighted* lobe:
``Int cos^n(theta) cos(theta) dw = 2 pi/(n+2)``, so at normal view (``r_o = n``, the lobe fully
above the horizon) the specular albedo is exactly ``ks``, and it decreases towards grazing views
(the lobe is cut by the horizon and weighted by smaller ``cos(theta_i)``); hence energy is
conserved iff ``kd + ks <= 1``, and it is as large as it can be at normal view. The constant
``(n+1)/(2 pi)`` that some renderers put in the BRDF is the normaliser of the lobe *without* the
cosine, i.e. the sampling density of the power-cosine lobe (models.md 2.5.2; used here by
:class:`~brdf_fit.models.phong.PhongOriginal` together with a ``1/cos(theta_i)``): as a BRDF
factor it reflects only ``ks (n+1)/(n+2)`` at normal view (0.9545 ks at n = 20, 0.5 ks at
n = 0), i.e. it loses energy for no reason. This library's ``modified-phong`` entry
(:class:`~brdf_fit.models.phong.ModifiedPhong`, Lafortune & Willems 1994) already uses
``(n+2)``: Lewis's model is the same function with Lewis's parameter names ``kd, ks``
(tests/test_lewis.py checks the identity); the difference between the two papers is their
derivation (Lewis: plausibility constraints on shaders; Lafortune & Willems: Monte Carlo
sampling), not the formula. Measured albedo of the default entry (red channel: kd = 0.4,
ks = 0.4, n = 30; :func:`brdf_fit.checks.run_checks`): 0.8000 = kd + ks at normal view, 0.6800 at
cos_o = 0.7, 0.5406 at 0.35, 0.4291 at 1e-3 (tests/test_lewis.py).

Reciprocal (``r_o.wi = r_i.wo``). Sampler (as modified Phong): with probability
``p_d = max kd/(max kd + max ks)`` the cosine hemisphere, else the power-cosine lobe
``(n+1)/(2 pi) cos^n`` about ``r_o``; ``pdf`` is the mixture density, and specular samples below
the horizon fail (pdf 0, weight 0). Quadrature hint ``("mirror", n)``.
"""

from __future__ import annotations

from brdf_fit.core.params import Entry, Param
from brdf_fit.core.validate import check_param, check_sum_at_most_one
from brdf_fit.models._lobes import check_exponent
from brdf_fit.models.phong import ModifiedPhong

__all__ = ["Lewis", "registry_entries"]

_LEWIS_1994 = (
    "R. R. Lewis, Making shaders more physically plausible, Fourth Eurographics Workshop on "
    "Rendering 1993; Computer Graphics Forum 13(2):109-120, 1994"
)


def Lewis(kd=0.4, ks=0.4, exponent=30.0) -> ModifiedPhong:
    """Lewis's normalised Phong BRDF ``kd/pi + ks (n+2)/(2 pi) cos^n(alpha_r)`` (Lewis 1994; see
    the module docstring for the normalisation and how it relates to modified Phong).

    ``kd``, ``ks`` (may carry channels) in [0, 1] with ``kd + ks <= 1`` per channel (energy
    conservation, validated for concrete values, in Lewis's parameter names); ``exponent``
    ``n >= 0`` a scalar. The function is :class:`~brdf_fit.models.phong.ModifiedPhong` (same
    eval, pdf and sampler), so it is built as one: ``rho_d = kd``, ``rho_s = ks``.
    """
    owner = "Lewis"
    check_param("kd", kd, lo=0.0, hi=1.0, owner=owner)
    check_param("ks", ks, lo=0.0, hi=1.0, owner=owner)
    check_exponent(exponent, owner)
    check_sum_at_most_one(kd, ks, "kd + ks", owner, why="energy conservation, Lewis 1994")
    return ModifiedPhong(rho_d=kd, rho_s=ks, exponent=exponent)


def registry_entries():
    """:class:`brdf_fit.registry.Entry` for Lewis's normalised Phong (not registered here)."""
    return [
        Entry(
            name="lewis",
            builder=lambda kd, ks, exponent: Lewis(kd=kd, ks=ks, exponent=exponent),
            params=(
                Param("kd", (0.4, 0.3, 0.2), lo=0.0, hi=1.0, channels=True,
                      doc="diffuse albedo (kd + ks <= 1)"),
                Param("ks", (0.4, 0.4, 0.4), lo=0.0, hi=1.0, channels=True,
                      doc="specular albedo at normal view (kd + ks <= 1)"),
                Param("exponent", 30.0, lo=0.0, hi=1e6, doc="Phong exponent n"),
            ),
            reference=f"{_LEWIS_1994}; models.md 4.18",
            description=(
                "physically plausible Phong kd/pi + ks (n+2)/(2 pi) cos^n(alpha_r): reciprocal, "
                "conserving iff kd + ks <= 1 (same function as modified-phong)"
            ),
            aliases=("lewis-phong", "plausible-phong"),
            year=1994,
            catalogue="Lewis",
            sampler="cosine + power-cosine lobe mixture (exact pdf)",
        ),
    ]
