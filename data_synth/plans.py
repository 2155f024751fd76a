"""Measurement plans: which (wi, wo) pairs a virtual gonioreflectometer measures.

Every plan function returns a :class:`Plan`: ``wi``, ``wo`` as (N, 3) float64 unit vectors in the
local frame (z = normal, both pointing away from the surface, strictly above the horizon) and
``info``, a JSON-able dict naming the plan and its arguments (stored in the dataset metadata, and
enough to rebuild the plan with :func:`make_plan`). A plan unpacks like a tuple:
``wi, wo = in_plane(...)``.

Angles: ``theta`` is the zenith angle from the normal, ``phi`` the azimuth from the tangent x,
both in degrees in the arguments.

Plans
-----
:func:`in_plane`         sweeps in the plane of incidence (the specular plane)
:func:`hemisphere_grid`  a full grid over both hemispheres (theta_i, phi_i, theta_o, phi_o)
:func:`four_axis`        a four-axis gonioreflectometer scan with its mechanical limits
:func:`random_sparse`    independent random directions (uniform or cosine-weighted)
:func:`merl_grid`        the half/difference grid of the MERL database

References: S. Rusinkiewicz, A new change of variables for efficient BRDF representation,
Eurographics Workshop on Rendering 1998 (half/difference angles); W. Matusik, H. Pfister, M. Brand,
L. McMillan, A data-driven reflectance model, ACM TOG 22(3) (SIGGRAPH) 2003 (the MERL grid and
its non-linear theta_h map).
"""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Iterator
from typing import Any

import numpy as np

from brdf_fit.core.frame import unit_from_angles, zenith_states_deg
from brdf_fit.core.limits import LimitError, check_bytes

__all__ = [
    "Plan",
    "PlanError",
    "in_plane",
    "hemisphere_grid",
    "four_axis",
    "random_sparse",
    "merl_grid",
    "PLANS",
    "make_plan",
    "unit_from_angles",
    "half_diff_to_io",
    "io_to_half_diff",
]


class PlanError(ValueError):
    """Invalid plan name or arguments (the message names the plan and the valid choices)."""


@dataclasses.dataclass(frozen=True)
class Plan:
    """A measurement plan: nominal directions and a description (see the module docstring).

    ``extra`` holds per-sample arrays some plans provide (``merl_grid``: ``"index"``, the (N, 3)
    MERL bin indices ``(i_theta_h, i_theta_d, i_phi_d)``)."""

    wi: np.ndarray
    wo: np.ndarray
    info: dict[str, Any]
    extra: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)

    def __iter__(self) -> Iterator[np.ndarray]:
        return iter((self.wi, self.wo))

    def __len__(self) -> int:
        return self.wi.shape[0]

    @property
    def n(self) -> int:
        return self.wi.shape[0]


# ----------------------------------------------------------------------------- helpers


def _angles(name: str, values, lo: float, hi: float, hi_open: bool = True) -> np.ndarray:
    a = np.atleast_1d(np.asarray(values, dtype=np.float64)).ravel()
    if a.size == 0:
        raise PlanError(f"{name} must not be empty")
    if not np.all(np.isfinite(a)):
        raise PlanError(f"{name} must be finite, got {a.tolist()}")
    bad = (a < lo) | ((a >= hi) if hi_open else (a > hi))
    if bad.any():
        rb = ")" if hi_open else "]"
        raise PlanError(f"{name} must lie in [{lo:g}, {hi:g}{rb} degrees, got {a[bad].tolist()}")
    return a


def _max_zenith(max_zenith_deg) -> float:
    m = float(max_zenith_deg)
    if not (0.0 < m < 90.0):
        raise PlanError(f"max_zenith_deg must lie in (0, 90) degrees, got {m:g}")
    return m


def _list(a) -> list[float]:
    return [float(x) for x in np.asarray(a).ravel()]


def _positive_int(name: str, value) -> int:
    try:
        v = int(value)
        ok = v == value and v >= 1 and not isinstance(value, bool)
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise PlanError(f"{name} must be a positive integer, got {value!r}")
    return v


#: memory a synthesised sample takes at its peak (its directions, the model's values and their
#: noise, the evaluation's intermediates and the file written): 270 bytes measured for a
#: 3-channel random_sparse plan of 10^6 samples through `brdf-fit synth` (483 MB peak against
#: 267 MB at 10^5), budgeted at twice that for more channels
BYTES_PER_SAMPLE = 512


def _check_count(plan: str, count: int) -> None:
    """Refuse a plan of ``count`` samples (computed from its arguments, before anything is
    allocated) whose synthesis would pass the memory limit (:mod:`brdf_fit.core.limits`)."""
    try:
        check_bytes(float(count) * BYTES_PER_SAMPLE,
                    f"plan {plan}: {count:,} samples at {BYTES_PER_SAMPLE} bytes each")
    except LimitError as e:
        raise PlanError(str(e)) from None


# ----------------------------------------------------------------------------- plans


def in_plane(
    theta_i_deg=(0.0, 15.0, 30.0, 45.0, 60.0, 75.0),
    theta_o_deg=tuple(range(-85, 86, 5)),
    phi_i_deg: float = 0.0,
) -> Plan:
    """Sweeps in the plane of incidence: every ``theta_i`` combined with every ``theta_o``.

    The source is at ``(theta_i, phi_i)``. A positive ``theta_o`` lies in the specular
    (forward) half of the plane, ``phi_o = phi_i + 180``; a negative one on the source side,
    ``phi_o = phi_i`` (back-scattering, ``theta_o = -theta_i`` is retro-reflection). This is the
    signed-angle convention of in-plane goniometer data. ``theta_i`` in [0, 90), ``theta_o`` in
    (-90, 90). Count: ``len(theta_i_deg) * len(theta_o_deg)`` (no sample is dropped; this plan
    has no mechanical model, see :func:`four_axis`).
    """
    ti = _angles("theta_i_deg", theta_i_deg, 0.0, 90.0)
    to = _angles("theta_o_deg", theta_o_deg, -90.0, 90.0)
    if (to <= -90.0).any():
        raise PlanError(f"theta_o_deg must be > -90 degrees, got {to[to <= -90].tolist()}")
    phi_i = float(phi_i_deg)
    TI, TO = np.meshgrid(ti, to, indexing="ij")
    TI, TO = TI.ravel(), TO.ravel()
    wi = unit_from_angles(TI, np.full_like(TI, phi_i))
    wo = unit_from_angles(np.abs(TO), np.where(TO >= 0, phi_i + 180.0, phi_i))
    info = {"name": "in_plane", "args": {"theta_i_deg": _list(ti), "theta_o_deg": _list(to),
                                         "phi_i_deg": phi_i}}
    return Plan(wi, wo, info)


def hemisphere_grid(
    n_theta_i: int = 7,
    n_theta_o: int = 7,
    n_phi: int = 12,
    max_zenith_deg: float = 85.0,
    n_phi_i: int = 1,
) -> Plan:
    """A full grid over both hemispheres.

    ``theta_i`` on ``linspace(0, max_zenith_deg, n_theta_i)`` and likewise ``theta_o``; ``phi_o``
    on ``360 k / n_phi``; ``phi_i`` on ``360 k / n_phi_i`` (``n_phi_i = 1``: ``phi_i = 0``, enough
    for isotropic materials; raise it for anisotropic ones). At ``theta = 0`` the azimuths
    coincide, so the pole is one state, not ``n_phi``. Count:
    ``S_i * S_o`` with ``S_i = 1 + (n_theta_i - 1) * n_phi_i`` and
    ``S_o = 1 + (n_theta_o - 1) * n_phi`` (each ``theta`` grid starts at 0).
    """
    n_ti = _positive_int("n_theta_i", n_theta_i)
    n_to = _positive_int("n_theta_o", n_theta_o)
    n_p = _positive_int("n_phi", n_phi)
    n_pi = _positive_int("n_phi_i", n_phi_i)
    mz = _max_zenith(max_zenith_deg)
    _check_count("hemisphere_grid", (1 + (n_ti - 1) * n_pi) * (1 + (n_to - 1) * n_p))
    di = zenith_states_deg(n_ti, n_pi, mz)
    do = zenith_states_deg(n_to, n_p, mz)
    wi = np.repeat(di, do.shape[0], axis=0)
    wo = np.tile(do, (di.shape[0], 1))
    info = {"name": "hemisphere_grid", "args": {"n_theta_i": n_ti, "n_theta_o": n_to,
                                                "n_phi": n_p, "max_zenith_deg": mz,
                                                "n_phi_i": n_pi}}
    return Plan(wi, wo, info)


def four_axis(
    theta_i_deg=tuple(range(0, 81, 10)),
    theta_o_deg=tuple(range(0, 81, 10)),
    phi_o_deg=tuple(range(0, 360, 15)),
    max_zenith_deg: float = 85.0,
    min_separation_deg: float = 5.0,
    phi_i_deg=(0.0,),
) -> Plan:
    """A scan of a four-axis gonioreflectometer, restricted by its mechanical limits.

    Mechanical model. The instrument has a source arm and a detector arm, each on a two-axis
    (zenith, azimuth) mount about the sample centre; equivalently a fixed source, a sample
    rotated about its normal and tilted, and a detector on a one- or two-axis arm: in the local
    frame both are the four angles ``(theta_i, phi_i, theta_o, phi_o)``. The machine scans the
    full grid of the arguments and skips every configuration it cannot reach or measure:

    * **zenith limit**: ``theta_i > max_zenith_deg`` or ``theta_o > max_zenith_deg`` (near
      grazing the beam footprint outgrows the sample and the arms would meet the sample stage);
    * **arm blocking**: the angle between ``wi`` and ``wo`` is below ``min_separation_deg``
      (around retro-reflection the detector head sits in the incident beam and occludes the
      source, or the arms collide). The angle is ``arccos(wi . wo)``, so the blocked region is
      a cone of that half-angle around ``wi`` (it spans azimuths near the pole).

    Configurations that coincide in direction space (``theta = 0`` at several azimuths) are kept:
    the machine measures them as repeated samples. Count: the grid size
    ``len(theta_i) * len(phi_i) * len(theta_o) * len(phi_o)`` minus the dropped samples; ``info``
    records the grid size and how many each limit removed (a sample violating both counts as
    zenith-limited).
    """
    ti = _angles("theta_i_deg", theta_i_deg, 0.0, 90.0)
    to = _angles("theta_o_deg", theta_o_deg, 0.0, 90.0)
    po = np.atleast_1d(np.asarray(phi_o_deg, dtype=np.float64)).ravel()
    pi_ = np.atleast_1d(np.asarray(phi_i_deg, dtype=np.float64)).ravel()
    for name, a in (("phi_o_deg", po), ("phi_i_deg", pi_)):
        if a.size == 0 or not np.all(np.isfinite(a)):
            raise PlanError(f"{name} must be a non-empty list of finite angles, got {a.tolist()}")
    mz = _max_zenith(max_zenith_deg)
    sep = float(min_separation_deg)
    if not (0.0 <= sep < 180.0):
        raise PlanError(f"min_separation_deg must lie in [0, 180) degrees, got {sep:g}")
    _check_count("four_axis", ti.size * pi_.size * to.size * po.size)
    TI, PI, TO, PO = (g.ravel() for g in np.meshgrid(ti, pi_, to, po, indexing="ij"))
    wi = unit_from_angles(TI, PI)
    wo = unit_from_angles(TO, PO)
    zenith_bad = (TI > mz) | (TO > mz)
    angle = np.degrees(np.arccos(np.clip(np.sum(wi * wo, axis=-1), -1.0, 1.0)))
    blocked = (angle < sep) & ~zenith_bad
    keep = ~(zenith_bad | blocked)
    info = {
        "name": "four_axis",
        "args": {"theta_i_deg": _list(ti), "theta_o_deg": _list(to), "phi_o_deg": _list(po),
                 "max_zenith_deg": mz, "min_separation_deg": sep, "phi_i_deg": _list(pi_)},
        "n_grid": int(TI.size),
        "n_dropped_zenith": int(zenith_bad.sum()),
        "n_dropped_blocked": int(blocked.sum()),
    }
    return Plan(wi[keep], wo[keep], info)


def random_sparse(
    n: int = 500,
    seed: int = 0,
    max_zenith_deg: float = 85.0,
    distribution: str = "uniform",
) -> Plan:
    """``n`` pairs of independent random directions on the cap ``theta <= max_zenith_deg``.

    ``distribution="uniform"``: uniform in solid angle (``cos theta`` uniform on
    ``[cos max, 1]``, ``phi`` uniform); ``"cosine"``: density proportional to ``cos theta``
    (``sin^2 theta`` uniform on ``[0, sin^2 max]``), which favours near-normal directions like a
    diffuse light field. ``wi`` and ``wo`` are drawn independently and identically from
    ``numpy.random.default_rng(seed)`` (this plan's own seed, so the directions do not change
    when the noise does). Count: exactly ``n``.
    """
    n_ = _positive_int("n", n)
    _check_count("random_sparse", n_)
    mz = _max_zenith(max_zenith_deg)
    if distribution not in ("uniform", "cosine"):
        raise PlanError(f"distribution must be 'uniform' or 'cosine', got {distribution!r}")
    rng = np.random.default_rng(int(seed))
    u = rng.random((2, n_, 2))
    cmax = np.cos(np.radians(mz))
    if distribution == "uniform":
        cos_t = 1.0 - u[..., 0] * (1.0 - cmax)
        sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t**2))
    else:
        sin_t = np.sqrt(u[..., 0] * (1.0 - cmax**2))
        cos_t = np.sqrt(1.0 - sin_t**2)
    phi = 2.0 * np.pi * u[..., 1]
    w = np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=-1)
    info = {"name": "random_sparse", "args": {"n": n_, "seed": int(seed), "max_zenith_deg": mz,
                                              "distribution": distribution}}
    return Plan(w[0], w[1], info)


# ----------------------------------------------------------------------------- MERL grid


def _rot_y(v, a):
    c, s = np.cos(a)[..., None], np.sin(a)[..., None]
    x, y, z = v[..., 0:1], v[..., 1:2], v[..., 2:3]
    return np.concatenate([c * x + s * z, y, -s * x + c * z], axis=-1)


def _rot_z(v, a):
    c, s = np.cos(a)[..., None], np.sin(a)[..., None]
    x, y, z = v[..., 0:1], v[..., 1:2], v[..., 2:3]
    return np.concatenate([c * x - s * y, s * x + c * y, z], axis=-1)


def half_diff_to_io(theta_h, phi_h, theta_d, phi_d):
    """``(wi, wo)`` from Rusinkiewicz's half/difference angles (radians).

    The half vector is ``h = (theta_h, phi_h)``; the difference vector ``d = (theta_d, phi_d)``
    is ``wi`` expressed in the frame where ``h`` is the pole: ``wi = R_z(phi_h) R_y(theta_h) d``
    and ``wo`` is ``wi`` reflected about ``h`` (Rusinkiewicz 1998, section 3; the convention of
    the MERL reader of Matusik et al. 2003)."""
    th, ph, td, pd = (np.asarray(a, dtype=np.float64) for a in (theta_h, phi_h, theta_d, phi_d))
    th, ph, td, pd = np.broadcast_arrays(th, ph, td, pd)
    d = np.stack([np.sin(td) * np.cos(pd), np.sin(td) * np.sin(pd), np.cos(td)], axis=-1)
    wi = _rot_z(_rot_y(d, th), ph)
    h = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
    wo = 2.0 * np.sum(wi * h, axis=-1, keepdims=True) * h - wi
    return wi, wo


def io_to_half_diff(wi, wo):
    """``(theta_h, phi_h, theta_d, phi_d)`` in radians from unit ``wi``, ``wo`` (the inverse of
    :func:`half_diff_to_io`; ``phi`` in (-pi, pi])."""
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    theta_h = np.arccos(np.clip(h[..., 2], -1.0, 1.0))
    phi_h = np.arctan2(h[..., 1], h[..., 0])
    d = _rot_y(_rot_z(wi, -phi_h), -theta_h)
    theta_d = np.arccos(np.clip(d[..., 2], -1.0, 1.0))
    phi_d = np.arctan2(d[..., 1], d[..., 0])
    return theta_h, phi_h, theta_d, phi_d


def merl_grid(
    n_theta_h: int = 90,
    n_theta_d: int = 90,
    n_phi_d: int = 180,
    subsample=1,
) -> Plan:
    """The half/difference grid of the MERL BRDF database at its bin centres.

    Bins (Matusik et al. 2003; Rusinkiewicz 1998 parameterisation, ``phi_h = 0`` since MERL
    assumes isotropy):

    * ``theta_h = ((i + 0.5) / n_theta_h)^2 * pi/2``: the centre, in the index variable, of
      MERL's non-linear bin ``i = floor(sqrt(theta_h / (pi/2)) * n_theta_h)``, which packs
      bins near the specular peak;
    * ``theta_d = (j + 0.5) / n_theta_d * pi/2``;
    * ``phi_d = (k + 0.5) / n_phi_d * pi`` (MERL stores ``phi_d`` in [0, pi): reciprocity
      folds ``phi_d + pi`` onto ``phi_d``).

    ``subsample`` (an int, or three ints for the three axes) keeps every ``s``-th bin index
    (``0, s, 2s, ...``). Pairs with ``wi`` or ``wo`` at or below the horizon are dropped (about
    a quarter of the full grid: MERL stores them but they hold no measurement). ``extra["index"]``
    gives each sample's ``(i, j, k)``. Count: the number of kept index triples; the full
    90 x 90 x 180 grid keeps 1,096,216 of 1,458,000 (see ``info["n_kept"]``).
    """
    nh = _positive_int("n_theta_h", n_theta_h)
    nd = _positive_int("n_theta_d", n_theta_d)
    npd = _positive_int("n_phi_d", n_phi_d)
    s = np.broadcast_to(np.asarray(subsample), (3,))
    sh, sd, sp = (_positive_int("subsample", v.item()) for v in s)
    _check_count("merl_grid", -(-nh // sh) * -(-nd // sd) * -(-npd // sp))
    i = np.arange(0, nh, sh)
    j = np.arange(0, nd, sd)
    k = np.arange(0, npd, sp)
    I, J, K = (g.ravel() for g in np.meshgrid(i, j, k, indexing="ij"))
    theta_h = ((I + 0.5) / nh) ** 2 * (np.pi / 2)
    theta_d = (J + 0.5) / nd * (np.pi / 2)
    phi_d = (K + 0.5) / npd * np.pi
    wi, wo = half_diff_to_io(theta_h, np.zeros_like(theta_h), theta_d, phi_d)
    keep = (wi[:, 2] > 0.0) & (wo[:, 2] > 0.0)
    info = {"name": "merl_grid",
            "args": {"n_theta_h": nh, "n_theta_d": nd, "n_phi_d": npd,
                     "subsample": [int(sh), int(sd), int(sp)]},
            "n_grid": int(I.size), "n_kept": int(keep.sum())}
    index = np.stack([I, J, K], axis=-1)[keep]
    return Plan(wi[keep], wo[keep], info, {"index": index})


# ----------------------------------------------------------------------------- by name

PLANS = {
    "in_plane": in_plane,
    "hemisphere_grid": hemisphere_grid,
    "four_axis": four_axis,
    "random_sparse": random_sparse,
    "merl_grid": merl_grid,
}


def make_plan(name: str, args: dict | None = None) -> Plan:
    """The plan called ``name`` (a key of :data:`PLANS`; ``-`` and ``_`` are interchangeable)
    built with keyword ``args``. Unknown names and arguments raise :class:`PlanError` listing
    the valid ones."""
    key = str(name).strip().lower().replace("-", "_")
    if key not in PLANS:
        raise PlanError(f"unknown plan {name!r}; valid plans: {', '.join(PLANS)}")
    fn = PLANS[key]
    args = dict(args or {})
    valid = list(inspect.signature(fn).parameters)
    unknown = [a for a in args if a not in valid]
    if unknown:
        raise PlanError(f"plan {key!r}: unknown argument(s) {', '.join(map(repr, unknown))}; "
                        f"valid arguments: {', '.join(valid)}")
    try:
        return fn(**args)
    except PlanError:
        raise
    except (TypeError, ValueError) as e:  # e.g. a string where a number belongs
        raise PlanError(f"plan {key!r}: invalid argument value ({e}); arguments were "
                        f"{args}") from None
