"""Does the data need two roughness widths? A test for azimuthal dependence, from the data.

**The statistic.** Two probe models are fitted to the data in the selection error
(:data:`brdf_fit.selection.selector.ERROR_DEFINITION`: the relative RMS error of the reflected
radiance, the metric every candidate is judged by): a Lambert base plus a GGX lobe
(height-correlated Smith G, Schlick Fresnel with RGB ``F0``), once with one width
(``alpha``) and once with two (``alpha_x`` along the tangent, ``alpha_y`` along the
bitangent; Heitz 2014, eq. 85), the second started from the first's optimum, so it nests it.
The statistic is the share of the isotropic probe's error that the second width removes,

    s = 1 - E_aniso / E_iso,

reported with both errors and the fitted width ratio ``max(alpha_x, alpha_y)/min(...)``.
Anisotropy is **present** when ``s >= THRESHOLD`` (0.25: a second width removes at least a
quarter of the error). An isotropic material leaves the second width nothing to explain but
noise and misfit of the probe's family; measured (``tests/selection/test_anisotropy.py`` and
the four renderer files of issue 28): ``s`` <= 0.016 for Mitsuba-rendered gold (GGX), copper
(Beckmann: the GGX probe misses it by 24% and a second width does not help), Mitsuba's
roughplastic, the demo's gold (1% noise) and the in-plane plastic example, against 0.988 for
Mitsuba-rendered brushed aluminium (0.08 x 0.25).

**Measurable.** Widths along x and y are told apart only by half vectors off both axes:
the test needs at least :data:`MIN_OFF_AXIS` samples with ``|h_x| >= 0.05`` and as many with
``|h_y| >= 0.05`` (unit half vector), else it reports ``measurable = False`` and
``present = False`` (an in-plane scan cannot show anisotropy).

**What it does not see**: an anisotropy axis that is not the frame's tangent (the probe has
no rotation angle: this package's frame convention puts the anisotropy axis on x, and data
measured in another frame should be rotated first), and anisotropy of a lobe shape other
than GGX's to the extent that a GGX lobe with two widths cannot mimic it.
"""

from __future__ import annotations

import dataclasses
import math
import time

import jax.numpy as jnp
import numpy as np

from brdf_fit.core.fresnel import SchlickFresnel
from brdf_fit.core.microfacet import GGX, SmithHeightCorrelated
from brdf_fit.data import GonioData
from brdf_fit.fitting.problem import FitError
from brdf_fit.fitting.single import fit
from brdf_fit.models._base import evaluate
from brdf_fit.models.lambert import Lambert
from brdf_fit.models.microfacet_brdf import MicrofacetBRDF
from brdf_fit.models.mixture import Mixture

__all__ = ["THRESHOLD", "MIN_OFF_AXIS", "AnisotropyTest", "detect_anisotropy"]

#: the share of the isotropic probe's radiance error a second width must remove (module
#: docstring: isotropic files measured <= 0.016, the anisotropic one 0.988)
THRESHOLD = 0.25
#: samples needed with a half vector off each axis (|h_x|, |h_y| >= OFF_AXIS)
MIN_OFF_AXIS = 10
OFF_AXIS = 0.05
STATISTIC = ("1 - E_aniso/E_iso: the share of the radiance error of an isotropic probe "
             "(Lambert + GGX, Schlick RGB F0) that a second GGX width removes")


@dataclasses.dataclass
class AnisotropyTest:
    """Outcome of :func:`detect_anisotropy` (module docstring)."""

    statistic: float | None
    threshold: float
    present: bool
    measurable: bool
    error_isotropic: float | None = None
    error_anisotropic: float | None = None
    width_ratio: float | None = None
    widths: tuple[float, float] | None = None
    seconds: float = 0.0
    note: str = ""

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["definition"] = STATISTIC
        d["widths"] = None if self.widths is None else list(self.widths)
        return d


def _probe(widths, rho, f0) -> Mixture:
    ax, ay = widths
    return Mixture(lobes=(Lambert(rho=rho), MicrofacetBRDF(
        distribution=GGX(ax, ay), masking=SmithHeightCorrelated(),
        fresnel=SchlickFresnel(f0))))


def _radiance_error(data: GonioData, model) -> float:
    w = np.ones_like(data.value) if data.weight is None else np.asarray(data.weight)
    c = np.clip(data.wi[:, 2:3], 0.0, None)
    m = np.asarray(evaluate(model, jnp.asarray(data.wi), jnp.asarray(data.wo)), np.float64)
    m = np.broadcast_to(m[:, None] if m.ndim == 1 else m, data.value.shape)
    num = float(np.sum(w * ((m - data.value) * c) ** 2))
    den = float(np.sum(w * (data.value * c) ** 2))
    return math.sqrt(num / den) if den > 0 else math.inf


def _off_axis_counts(data: GonioData) -> tuple[int, int]:
    h = np.asarray(data.wi) + np.asarray(data.wo)
    h /= np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    used = np.ones(data.n, bool) if data.weight is None else np.any(
        np.asarray(data.weight) > 0, axis=-1)
    return (int(np.sum(used & (np.abs(h[:, 0]) >= OFF_AXIS))),
            int(np.sum(used & (np.abs(h[:, 1]) >= OFF_AXIS))))


def detect_anisotropy(data: GonioData, threshold: float = THRESHOLD,
                      max_steps: int = 256) -> AnisotropyTest:
    """The anisotropy test of the module docstring on ``data`` (its sigma set aside, as the
    selection error does)."""
    t0 = time.perf_counter()
    nx, ny = _off_axis_counts(data)
    if min(nx, ny) < MIN_OFF_AXIS:
        return AnisotropyTest(
            statistic=None, threshold=threshold, present=False, measurable=False,
            seconds=time.perf_counter() - t0,
            note=(f"not measurable from this geometry: {nx} samples with |h_x| >= {OFF_AXIS} "
                  f"and {ny} with |h_y| >= {OFF_AXIS} (need {MIN_OFF_AXIS} of each)"))
    plain = dataclasses.replace(data, sigma=None)
    c = data.n_channels
    rho0 = jnp.full((c,), 0.1)
    f00 = jnp.full((c,), 0.5)
    try:
        iso = fit(plain, _probe((jnp.asarray(0.2), None), rho0, f00), metric="absolute",
                  cos_weight=True, max_steps=max_steps)
        p = iso.params
        a = p["lobes.1.distribution.alpha_x"]
        start = _probe((jnp.asarray(a), jnp.asarray(a)), jnp.asarray(p["lobes.0.rho"]),
                       jnp.asarray(p["lobes.1.fresnel.f0"]))
        an = fit(plain, start, metric="absolute", cos_weight=True, max_steps=max_steps,
                 guess="none")
    except FitError as exc:
        return AnisotropyTest(statistic=None, threshold=threshold, present=False,
                              measurable=True, seconds=time.perf_counter() - t0,
                              note=f"a probe could not be fitted: {exc}")
    e_iso = _radiance_error(data, iso.model)
    e_an = min(_radiance_error(data, an.model), e_iso)  # nested: never worse than iso
    s = 1.0 - e_an / e_iso if e_iso > 0 else 0.0
    ax = float(an.params["lobes.1.distribution.alpha_x"])
    ay = float(an.params["lobes.1.distribution.alpha_y"])
    ratio = max(ax, ay) / max(min(ax, ay), 1e-300)
    present = bool(s >= threshold)
    note = (f"anisotropic: a second width removes {100 * s:.1f}% of the isotropic probe's "
            f"error (threshold {100 * threshold:g}%); widths {ax:.4g} (x) and {ay:.4g} (y)"
            if present else
            f"isotropic: a second width removes {100 * s:.1f}% of the isotropic probe's error "
            f"(threshold {100 * threshold:g}%)")
    return AnisotropyTest(statistic=float(s), threshold=threshold, present=present,
                          measurable=True, error_isotropic=float(e_iso),
                          error_anisotropic=float(e_an), width_ratio=float(ratio),
                          widths=(ax, ay), seconds=time.perf_counter() - t0, note=note)
