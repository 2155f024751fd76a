"""Model-mismatch conversion: fit GGX to Phong-family lobes and compare with the closed forms.

:func:`phong_to_ggx` synthesises **noise-free** samples of a source lobe (registry
``modified-phong`` with ``rho_d = 0``, ``blinn-phong`` or ``blinn-phong-approx``) at each exponent,
fits registry ``ggx`` (``alpha`` and a mono ``f0`` free) with :func:`brdf_fit.fit.fit`, and
reports the fitted width next to the closed-form width of :mod:`brdf_fit.convert_phong`
(Walter et al. 2007's peak match ``alpha = sqrt(2/(n+2))``; a Phong exponent goes through
:func:`~brdf_fit.convert.phong.phong_to_blinn_phong_exponent` first, ``n_blinn = 4 n_phong``).

Geometry (:func:`geometry`, stated in every result): the union of

* a **hemisphere grid** (the directions of :func:`data_synth.plans.hemisphere_grid`, built from
  :func:`brdf_fit.core.frame.zenith_states_deg`: ``theta_i`` and ``theta_o`` on
  ``linspace(0, max_zenith_deg, 5)`` and ``(.., 9)``, ``phi_i = 0``, ``phi_o`` on 12 azimuths):
  the wide, in-plane and off-plane part where the GGX tails show;
* a **lobe grid**: for ``theta_i`` in :data:`LOBE_THETA_I_DEG` (``phi_i = 0``), half vectors
  ``h`` at ``theta_h = s w`` with ``s`` in ``0, 0.25, ..., 3`` and 16 azimuths ``phi_h``, and
  ``wo = 2 (wi.h) h - wi``. ``w = sqrt(2/(n_b + 2))`` (radians) is the closed-form width at the
  equivalent Blinn-Phong exponent ``n_b``, so the lobe is resolved the same way at every exponent
  (``cos^n_b(theta_h) ~ exp(-s^2)``: ``s = 3`` reaches 1e-4 of the Blinn-Phong peak).

Samples with either direction beyond ``max_zenith_deg`` are dropped. The scale of the source is
chosen so that the **peak-matched** GGX ``f0`` is :data:`PEAK_F0` (0.5, inside ``[0, 1]``, so that
the start is far from the bound; the bound can still decide a fit: with ``metric="absolute"`` at
``n = 100, 1000`` the fitted ``f0`` runs to 1 and the fit is reported not converged): at normal
view GGX peaks at ``f0/(4 pi alpha^2)``; the sources at
``rho_s K(n)``. The fitted ``f0`` therefore also shows how far the best fit moves off the peak.

Residuals (per exponent): ``residual_rms``, the rms of the fit metric's residual (``log``:
``ln(1 + m cos_i) - ln(1 + f cos_i)``, see :mod:`brdf_fit.fit`); ``max_rel_err``, the largest
``|m - f|/f`` over the lobe core (samples where the source is at least :data:`CORE_FRACTION` of
its largest value); ``max_err_over_peak``, the largest ``|m - f|`` over all samples divided by the
source's largest value; ``radiance_error``, the relative RMS error of the reflected radiance
``f cos(theta_i)`` over all samples (the error :mod:`brdf_fit.selection` judges models by). A row
``represents`` its source when ``radiance_error <= REPRESENTS_TOL`` (10%); measured with the
default log metric, no row does (0.53-1.6 for n = 10-1000, largest at 80 degree zeniths where
GGX's Fresnel and ``1/(4 cos cos)`` grow and the Phong lobes do not; 0.4-0.6 even below 30
degrees), so the command says so and exits with status 1. ``closed_rms`` is the same rms for
GGX at the closed-form ``alpha`` and the peak-matched ``f0`` (no fit).

The result's ``rows`` (exponent -> alpha, f0) are a small fitted lookup table;
:func:`alpha_from_table` interpolates it (linearly in ``log n``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence

import numpy as np

from brdf_fit import registry
from brdf_fit.convert import phong as cp
from brdf_fit.convert.error import radiance_error
from brdf_fit.core.frame import unit_from_angles, zenith_states_deg
from brdf_fit.data import GonioData
from brdf_fit.fitting.single import METRICS, RELATIVE_FLOOR, fit

__all__ = [
    "SOURCES",
    "ConversionError",
    "PhongToGGXRow",
    "PhongToGGXResult",
    "geometry",
    "source_scale",
    "phong_to_ggx",
    "alpha_from_table",
]

#: Source registry entries and the kind of their exponent.
#: ``blinn-phong-microfacet`` (the Blinn-Phong NDF inside the microfacet BRDF, Schlick F, Smith G at
#: the Beckmann-mapped width) is a control: it differs from GGX in D alone.
SOURCES = {"modified-phong": "phong", "blinn-phong": "blinn-phong",
           "blinn-phong-approx": "blinn-phong", "blinn-phong-microfacet": "blinn-phong"}
DEFAULT_EXPONENTS = (1.0, 10.0, 100.0, 1000.0)
#: GGX f0 that matches the source's normal-view peak (see the module docstring).
PEAK_F0 = 0.5
#: The lobe core for ``max_rel_err``: samples where the source is >= this fraction of its maximum.
CORE_FRACTION = 0.1
#: the largest radiance error at which a fitted GGX is said to represent its source
REPRESENTS_TOL = 0.1
LOBE_THETA_I_DEG = (0.0, 15.0, 30.0, 45.0, 60.0, 75.0)
LOBE_S = tuple(0.25 * k for k in range(13))
LOBE_N_PHI = 16
GRID = {"n_theta_i": 5, "n_theta_o": 9, "n_phi": 12}


class ConversionError(ValueError):
    """A conversion request that cannot be honoured (unknown source, bad exponent or zenith)."""


@dataclasses.dataclass
class PhongToGGXRow:
    """One exponent's conversion (see the module docstring for every field)."""

    exponent: float
    blinn_phong_exponent: float
    source_scale: float
    alpha_fit: float
    f0_fit: float
    alpha_closed: float
    ratio: float
    residual_rms: float
    closed_rms: float
    max_rel_err: float
    max_err_over_peak: float
    radiance_error: float
    represents: bool
    converged: bool
    steps: int
    n_samples: int
    seconds: float

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclasses.dataclass
class PhongToGGXResult:
    """Outcome of :func:`phong_to_ggx`: the rows and a statement of what was matched where."""

    source: str
    target: str
    metric: str
    geometry: str
    max_zenith_deg: float
    closed_form: str
    rows: list[PhongToGGXRow]

    def to_dict(self) -> dict:
        return {"source": self.source, "target": self.target, "metric": self.metric,
                "geometry": self.geometry, "max_zenith_deg": self.max_zenith_deg,
                "closed_form": self.closed_form, "error_measures": ERROR_MEASURES,
                "rows": [r.to_dict() for r in self.rows]}


ERROR_MEASURES = {
    "residual_rms": "rms of the fit metric's residual over all samples (noise-free data)",
    "closed_rms": "the same for GGX at alpha_closed, f0 = peak-matched (no fit)",
    "max_rel_err": f"max |m - f|/f where the source f >= {CORE_FRACTION:g} x its maximum",
    "max_err_over_peak": "max |m - f| over all samples / max f",
    "radiance_error": "sqrt(sum (m - f)^2 cos_i^2 / sum f^2 cos_i^2) over all samples",
    "represents": f"radiance_error <= {REPRESENTS_TOL:g}",
    "ratio": "alpha_fit / alpha_closed",
}


def _source_name(source: str) -> str:
    key = str(source).strip().lower()

    try:
        key = registry.get(key).name
    except KeyError:
        pass
    if key not in SOURCES:
        raise ConversionError(f"unknown source {source!r}; valid sources: {', '.join(SOURCES)}")
    return key


def _blinn_exponent(source: str, n: float) -> float:

    return float(cp.phong_to_blinn_phong_exponent(n)) if SOURCES[source] == "phong" else float(n)


def _closed_alpha(source: str, n: float) -> float:

    return float(cp.blinn_phong_to_ggx_alpha(_blinn_exponent(source, n)))


def source_scale(source: str, n: float, peak_f0: float = PEAK_F0) -> float:
    """``rho_s`` of the source for which the peak-matched GGX ``f0`` is ``peak_f0`` (for
    ``blinn-phong-microfacet``: its ``f0``, which is ``peak_f0`` itself).

    GGX at normal view peaks at ``f0/(4 pi alpha^2) = f0 (n_b + 2)/(8 pi)`` with Walter's
    ``alpha^2 = 2/(n_b + 2)``; the sources peak at ``rho_s K``: ``blinn-phong``
    ``K = (n+2)/(2 pi)``, ``blinn-phong-approx`` ``(n+8)/(8 pi)``, ``modified-phong``
    ``(n+2)/(2 pi)`` with ``n_b = 4 n``."""
    source = _source_name(source)
    if source == "blinn-phong-microfacet":
        return float(peak_f0)
    nb = _blinn_exponent(source, n)
    ggx_peak = peak_f0 * (nb + 2.0) / (8.0 * math.pi)
    if source == "blinn-phong":
        k = (n + 2.0) / (2.0 * math.pi)
    elif source == "blinn-phong-approx":
        k = (n + 8.0) / (8.0 * math.pi)
    else:
        k = (n + 2.0) / (2.0 * math.pi)
    return ggx_peak / k


def geometry(width: float, max_zenith_deg: float = 80.0) -> tuple[np.ndarray, np.ndarray]:
    """``(wi, wo)`` of the stated geometry (module docstring) for a lobe of closed-form width
    ``width`` (radians, in half-vector space)."""
    di = zenith_states_deg(GRID["n_theta_i"], GRID.get("n_phi_i", 1), max_zenith_deg)
    do = zenith_states_deg(GRID["n_theta_o"], GRID["n_phi"], max_zenith_deg)
    wis = [np.repeat(di, do.shape[0], axis=0)]
    wos = [np.tile(do, (di.shape[0], 1))]
    th = np.asarray(LOBE_S) * width
    ph = 2.0 * math.pi * np.arange(LOBE_N_PHI) / LOBE_N_PHI
    T, P = np.meshgrid(th[1:], ph, indexing="ij")
    T = np.concatenate([[0.0], T.ravel()])
    P = np.concatenate([[0.0], P.ravel()])
    ok_h = T < 0.5 * math.pi
    h = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)[ok_h]
    for ti in LOBE_THETA_I_DEG:
        if ti > max_zenith_deg:
            continue
        wi = np.broadcast_to(unit_from_angles(ti, 0.0), h.shape)
        d = np.sum(wi * h, -1, keepdims=True)
        wo = 2.0 * d * h - wi
        wo = wo / np.linalg.norm(wo, axis=-1, keepdims=True)
        wis.append(wi[d[:, 0] > 0])
        wos.append(wo[d[:, 0] > 0])
    wi = np.concatenate(wis)
    wo = np.concatenate(wos)
    cz = math.cos(math.radians(max_zenith_deg))
    keep = (wi[:, 2] >= cz) & (wo[:, 2] >= cz) & (wo[:, 2] > 0)
    return np.ascontiguousarray(wi[keep]), np.ascontiguousarray(wo[keep])


def _geometry_text(max_zenith_deg: float) -> str:
    s_max = LOBE_S[-1]
    return (
        f"hemisphere grid (theta_i, theta_o on linspace(0, {max_zenith_deg:g} deg, "
        f"{GRID['n_theta_i']}/{GRID['n_theta_o']}), phi_i = 0, {GRID['n_phi']} phi_o; in- and "
        f"off-plane) + lobe grid (theta_i in {', '.join(f'{t:g}' for t in LOBE_THETA_I_DEG)} deg; "
        f"half vectors at theta_h = s w, s = 0..{s_max:g} step {LOBE_S[1]:g}, {LOBE_N_PHI} phi_h; "
        f"w = sqrt(2/(n_b+2)) rad); both directions within {max_zenith_deg:g} deg of the normal"
    )


def _validate(exponents, metric, max_zenith_deg):

    if metric not in METRICS:
        raise ConversionError(f"unknown metric {metric!r}; valid metrics: {', '.join(METRICS)}")
    if not (0.0 < float(max_zenith_deg) < 90.0):
        raise ConversionError(f"max_zenith_deg must lie in (0, 90) degrees, got "
                              f"{max_zenith_deg:g}")
    ex = [float(n) for n in exponents]
    if not ex:
        raise ConversionError("give at least one exponent")
    bad = [n for n in ex if not (math.isfinite(n) and 0.0 < n <= 1e6)]
    if bad:
        raise ConversionError(f"exponents must lie in (0, 1e6], got {bad}")
    return ex


_EVAL = None


def _eval(model, wi: np.ndarray, wo: np.ndarray, size: int | None = None) -> np.ndarray:
    """``model.eval(wi, wo)`` as float64 NumPy, jitted, the directions padded to ``size`` rows
    (the normal; dropped again) so that every exponent's geometry shares one compiled program
    per model class. Eagerly, each of a model's operations is dispatched on its own (and, for
    each new geometry size, compiled or looked up in the persistent cache): three evaluations
    per exponent were most of a warm ``brdf-fit convert phong-to-ggx``."""
    global _EVAL
    if _EVAL is None:
        import equinox as eqx

        _EVAL = eqx.filter_jit(lambda m, a, b: m.eval(a, b))
    n = wi.shape[0]
    extra = max(int(size or n) - n, 0)
    if extra:
        z = np.zeros((extra, 3), wi.dtype)
        z[:, 2] = 1.0
        wi, wo = np.concatenate([wi, z]), np.concatenate([wo, z])
    return np.asarray(_EVAL(model, wi, wo), float)[:n]


def _one(source: str, n: float, metric: str, max_zenith_deg: float,
         pad_to: int | None = None) -> PhongToGGXRow:
    t0 = time.perf_counter()
    nb = _blinn_exponent(source, n)
    a_closed = _closed_alpha(source, n)
    scale = source_scale(source, n)
    wi, wo = geometry(a_closed, max_zenith_deg)
    src = registry.get(source)
    params = {"f0" if "f0" in src.param_names else "rho_s": scale, "exponent": n}
    if "rho_d" in src.param_names:
        params["rho_d"] = 0.0
    f = _eval(src.build(**params), wi, wo, pad_to)
    data = GonioData(wi=wi, wo=wo, value=f[:, None], channels=("Y",),
                     metadata={"source": source, "params": params})
    init = {"alpha": min(a_closed, 0.999), "f0": PEAK_F0}
    r = fit(data, "ggx", init=init, metric=metric, pad_to=pad_to)
    ggx = registry.get("ggx")
    m = _eval(r.model, wi, wo, pad_to).reshape(-1)
    m_closed = _eval(ggx.build(alpha=min(a_closed, 1.0), f0=PEAK_F0), wi, wo,
                     pad_to).reshape(-1)
    c = wi[:, 2]
    core = f >= CORE_FRACTION * f.max()
    alpha_fit = float(np.asarray(r.params["alpha"]))
    rad = radiance_error(f, m, wi)
    return PhongToGGXRow(
        exponent=float(n),
        blinn_phong_exponent=nb,
        source_scale=float(scale),
        alpha_fit=alpha_fit,
        f0_fit=float(np.asarray(r.params["f0"]).reshape(-1)[0]),
        alpha_closed=a_closed,
        ratio=alpha_fit / a_closed,
        residual_rms=float(r.residual_rms),
        closed_rms=_metric_rms(metric, m_closed, f, c),
        max_rel_err=float(np.max(np.abs(m[core] - f[core]) / f[core])),
        max_err_over_peak=float(np.max(np.abs(m - f)) / f.max()),
        radiance_error=rad,
        represents=bool(rad <= REPRESENTS_TOL),
        converged=bool(r.converged),
        steps=int(r.steps),
        n_samples=int(r.n_samples),
        seconds=time.perf_counter() - t0,
    )


def _metric_rms(metric: str, m, f, c) -> float:
    """rms of :mod:`brdf_fit.fit`'s metric residual (unit weights, no sigma), in NumPy."""

    if metric == "log":
        g = np.log1p(m * c) - np.log1p(f * c)
    elif metric == "cuberoot":
        g = np.cbrt(m) - np.cbrt(f)
    elif metric == "relative":
        g = (m - f) / np.maximum(f, RELATIVE_FLOOR * np.max(np.abs(f)))
    else:
        g = m - f
    return float(np.sqrt(np.mean(g**2)))


def phong_to_ggx(
    source: str = "modified-phong",
    exponents: Sequence[float] = DEFAULT_EXPONENTS,
    metric: str = "log",
    max_zenith_deg: float = 80.0,
    progress=None,
) -> PhongToGGXResult:
    """Fit GGX (``alpha``, mono ``f0``) to noise-free ``source`` lobes at each exponent and
    compare with the closed form (module docstring). Runs in float64 if x64 is enabled (the CLI
    enables it); each exponent is one :func:`brdf_fit.fit.fit` call from the closed-form start.
    ``progress(done, total, exponent)`` is called before each exponent."""
    source = _source_name(source)
    ex = _validate(exponents, metric, max_zenith_deg)
    rows = []
    # one padded size for every exponent's geometry: one compiled solver for the whole series
    size = max(geometry(_closed_alpha(source, n), max_zenith_deg)[0].shape[0] for n in ex)
    for k, n in enumerate(ex):
        if progress is not None:
            progress(k, len(ex), n)
        rows.append(_one(source, n, metric, float(max_zenith_deg), pad_to=size))
    via = ("phong_to_blinn_phong_exponent (n_b = 4 n), then blinn_phong_to_ggx_alpha"
           if SOURCES[source] == "phong" else "blinn_phong_to_ggx_alpha")
    return PhongToGGXResult(
        source=source, target="ggx", metric=metric, geometry=_geometry_text(max_zenith_deg),
        max_zenith_deg=float(max_zenith_deg),
        closed_form=f"alpha = sqrt(2/(n_b + 2)) (Walter et al. 2007, peak match) via "
                    f"brdf_fit.convert.phong.{via}",
        rows=rows,
    )


def alpha_from_table(table, exponent):
    """GGX ``alpha`` at ``exponent`` from a fitted table (a :class:`PhongToGGXResult`, its
    ``to_dict()`` or the CLI's ``--json``), interpolated linearly in ``log n`` (clamped to the
    table's ends)."""
    rows = table.rows if isinstance(table, PhongToGGXResult) else table["rows"]
    rows = [r.to_dict() if isinstance(r, PhongToGGXRow) else r for r in rows]
    rows = sorted(rows, key=lambda r: r["exponent"])
    x = np.log([r["exponent"] for r in rows])
    y = np.asarray([r["alpha_fit"] for r in rows])
    return np.interp(np.log(np.asarray(exponent, float)), x, y)
