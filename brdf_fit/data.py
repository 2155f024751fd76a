"""Gonioreflectometer measurements in canonical form: :class:`GonioData`.

One sample is a pair of directions and a BRDF value per channel:

``wi``, ``wo``   (N, 3) unit vectors in the local frame (z = normal), pointing away from the surface
``value``        (N, C) BRDF in 1/sr (not multiplied by the cosine), C channels
``weight``       (N, C) non-negative per-sample weights; 0 masks a sample (missing, saturated,
                 below the horizon); ``1/sigma^2`` when uncertainties are known
``sigma``        (N, C) standard deviations of ``value``, or None
``channels``     C channel names: ``("R", "G", "B")``, ``("Y",)`` or wavelengths ``("550nm", ...)``
``metadata``     free JSON-able dict (instrument, recipe, provenance, units)

Readers convert every file layout (degrees, BRF, BRDF times cos) into this form and validate it
with :meth:`GonioData.validate`, which names the sample and the problem instead of letting an
error surface deep inside JAX.
"""

from __future__ import annotations

import dataclasses
import re
from typing import Any

import numpy as np

__all__ = ["GonioData", "DataError", "MAX_VALUE", "UNIT_TOL", "unit_directions", "check_values",
           "wavelength_channels", "channel_wavelengths", "SUBSAMPLES", "subsample_index",
           "half_difference_strata"]


class DataError(ValueError):
    """Invalid measurement data (the message names the sample, column or field)."""


#: Unit-length tolerance for directions: values written with 6 significant digits (CSV angles in
#: degrees to 1e-4) reproduce unit vectors to ~1e-6; 1e-4 accepts those, rejects real errors.
UNIT_TOL = 1e-4
#: Largest |BRDF value| (1/sr) a data file may hold. No registry model reaches it at any
#: parameter value the registry allows (GGX at its smallest width, alpha = 1e-4, peaks near 1e7
#: at normal incidence; MERL's measured materials stay below 1e4), so a larger value is a
#: corrupt field or a unit mix-up, and refusing it keeps every sum of squares a fit forms
#: (1e30 per sample) far inside float64: one value of 1e300 used to overflow the normal
#: equations and hang the fit in an SVD of infinities.
MAX_VALUE = 1e15


#: a direction shorter than this is no direction at all (refused by :func:`unit_directions`)
DIRECTION_MIN_LENGTH = 1e-12


def _where(bad: np.ndarray) -> str:
    """``"N rows, the first at index I"`` of a boolean mask over rows."""
    idx = np.flatnonzero(bad)
    return f"{idx.size} row(s), the first at index {int(idx[0])}"


def unit_directions(a, what: str) -> np.ndarray:
    """``(M, 3)`` directions as unit vectors, the rule every reader of bare direction arrays
    follows (image stacks, ``fit-batch --geometry``): a row is normalised where its length
    differs from 1 by more than :data:`UNIT_TOL`, and refused with :class:`DataError`, naming
    ``what``, how many rows and the first, where it is not finite, shorter than
    :data:`DIRECTION_MIN_LENGTH`, or below the horizon (z < 0)."""
    v = np.asarray(a, float)
    if v.ndim != 2 or v.shape[1] != 3:
        raise DataError(f"{what}: directions must have shape (M, 3), got {v.shape}")
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        raise DataError(f"{what}: not finite in {_where(bad)}")
    n = np.linalg.norm(v, axis=1)
    bad = n < DIRECTION_MIN_LENGTH
    if bad.any():
        raise DataError(f"{what}: zero-length direction in {_where(bad)}")
    v = np.where((np.abs(n - 1.0) > UNIT_TOL)[:, None], v / n[:, None], v)
    bad = v[:, 2] < 0.0
    if bad.any():
        raise DataError(f"{what}: below the horizon (z < 0) in {_where(bad)}")
    return v


def check_values(values, what: str, block: int = 1 << 20) -> None:
    """Refuse an array of measured values (any shape, e.g. a memory-mapped ``(N, M, C)``)
    holding a negative or non-finite number, with :class:`DataError` naming ``what``, how many
    and the first (as an index of the array); read ``block`` values at a time, so a
    memory-mapped file is scanned without being loaded (a negative value made every fit fail
    with nothing saying why; issue 45)."""
    flat = np.asarray(values).reshape(-1)  # a view of a contiguous (memory-mapped) array
    counts = {"negative": 0, "non-finite": 0}
    first = {}
    for s in range(0, flat.shape[0], block):
        chunk = np.asarray(flat[s:s + block])
        for kind, bad in (("non-finite", ~np.isfinite(chunk)), ("negative", chunk < 0)):
            k = int(np.count_nonzero(bad))
            if k:
                counts[kind] += k
                first.setdefault(kind, s + int(np.flatnonzero(bad)[0]))
    shape = np.shape(values)
    for kind in ("non-finite", "negative"):
        if counts[kind]:
            idx = tuple(int(i) for i in np.unravel_index(first[kind], shape))
            raise DataError(f"{what}: {counts[kind]:,} {kind} value(s), the first at index "
                            f"{idx} ({np.asarray(values)[idx]!r}); BRDF values are finite and >= 0")


def wavelength_channels(wavelengths_nm) -> tuple[str, ...]:
    """Channel names for spectral data: ``("400nm", "410nm", ...)``."""
    return tuple(f"{float(w):g}nm" for w in np.asarray(wavelengths_nm, float))


def channel_wavelengths(channels) -> np.ndarray | None:
    """Wavelengths (nm) if every channel is named ``<number>nm``, else None."""
    vals = []
    for c in channels:
        m = re.fullmatch(r"\s*([0-9.]+)\s*nm\s*", str(c))
        if not m:
            return None
        vals.append(float(m.group(1)))
    return np.asarray(vals)


@dataclasses.dataclass(frozen=True)
class GonioData:
    """Measured (or synthesised) BRDF samples in canonical form (see the module docstring)."""

    wi: np.ndarray
    wo: np.ndarray
    value: np.ndarray
    weight: np.ndarray | None = None
    sigma: np.ndarray | None = None
    channels: tuple[str, ...] = ("Y",)
    metadata: dict[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        wi = np.asarray(self.wi, dtype=np.float64)
        wo = np.asarray(self.wo, dtype=np.float64)
        value = np.asarray(self.value, dtype=np.float64)
        if value.ndim == 1:
            value = value[:, None]
        n = value.shape[0]
        def per_sample(name, a):
            # a 1-D weight or sigma of a 1-D value is per sample, like the value: (N,) -> (N, 1)
            a = np.asarray(a, np.float64)
            if a.ndim == 1 and a.shape[0] == n and value.shape[1] != n:
                a = a[:, None]
            try:
                return np.broadcast_to(a, value.shape).copy()
            except ValueError:
                raise DataError(f"{name} has shape {a.shape}, which does not match value's "
                                f"{value.shape} (N samples x C channels)") from None

        weight = np.ones_like(value) if self.weight is None else per_sample("weight", self.weight)
        sigma = None if self.sigma is None else per_sample("sigma", self.sigma)
        object.__setattr__(self, "wi", wi)
        object.__setattr__(self, "wo", wo)
        object.__setattr__(self, "value", value)
        object.__setattr__(self, "weight", weight)
        object.__setattr__(self, "sigma", sigma)
        object.__setattr__(self, "channels", tuple(str(c) for c in self.channels))
        object.__setattr__(self, "metadata", dict(self.metadata))
        if wi.shape != (n, 3) or wo.shape != (n, 3):
            raise DataError(
                f"wi and wo must have shape ({n}, 3) to match {n} values, got {wi.shape} and "
                f"{wo.shape}"
            )
        if len(self.channels) != value.shape[1]:
            raise DataError(
                f"{value.shape[1]} value column(s) but {len(self.channels)} channel name(s) "
                f"{self.channels}"
            )

    # ------------------------------------------------------------------ properties

    @property
    def n(self) -> int:
        return self.value.shape[0]

    @property
    def n_channels(self) -> int:
        return self.value.shape[1]

    @property
    def wavelengths_nm(self) -> np.ndarray | None:
        return channel_wavelengths(self.channels)

    def __len__(self) -> int:
        return self.n

    # ------------------------------------------------------------------ validation

    def validate(self, allow_negative_sigmas: float = 5.0) -> GonioData:
        """Raise :class:`DataError` naming the first offending sample: non-finite numbers,
        values beyond :data:`MAX_VALUE` in magnitude, non-unit directions, directions below the
        horizon with non-zero weight, negative weights,
        or values more negative than ``allow_negative_sigmas`` standard deviations (noise can make
        a measured value slightly negative; beyond that it is an error). Returns ``self``."""

        def first(mask):
            return int(np.flatnonzero(mask.reshape(self.n, -1).any(-1))[0])

        for name in ("wi", "wo", "value", "weight"):
            arr = getattr(self, name)
            bad = ~np.isfinite(arr)
            if bad.any():
                i = first(bad)
                raise DataError(f"sample {i}: {name} is not finite ({arr[i].tolist()})")
        for name in ("wi", "wo"):
            arr = getattr(self, name)
            norm = np.linalg.norm(arr, axis=-1)
            bad = np.abs(norm - 1.0) > UNIT_TOL
            if bad.any():
                i = first(bad)
                raise DataError(f"sample {i}: {name} is not a unit vector (length {norm[i]:.6g})")
        used = self.weight > 0
        for name in ("wi", "wo"):
            below = (getattr(self, name)[:, 2] <= 0)[:, None] & used
            if below.any():
                i = first(below)
                theta = np.degrees(np.arccos(np.clip(getattr(self, name)[i, 2], -1, 1)))
                raise DataError(
                    f"sample {i}: {name} is at or below the horizon (theta = {theta:.4g} deg) "
                    "but has non-zero weight"
                )
        huge = np.abs(self.value) > MAX_VALUE
        if huge.any():
            i = first(huge)
            raise DataError(f"sample {i}: value {self.value[i].tolist()} exceeds {MAX_VALUE:g} "
                            "1/sr in magnitude (brdf_fit.data.MAX_VALUE): not a BRDF value")
        if (self.weight < 0).any():
            i = first(self.weight < 0)
            raise DataError(f"sample {i}: negative weight {self.weight[i].tolist()}")
        if self.sigma is not None:
            if (~np.isfinite(self.sigma) | (self.sigma < 0)).any():
                i = first(~np.isfinite(self.sigma) | (self.sigma < 0))
                raise DataError(f"sample {i}: sigma must be finite and >= 0, got "
                                f"{self.sigma[i].tolist()}")
            too_negative = (self.value < -allow_negative_sigmas * self.sigma) & used
        else:
            too_negative = (self.value < 0) & used
        if too_negative.any():
            i = first(too_negative)
            what = (f"more than {allow_negative_sigmas:g} sigma below 0"
                    if self.sigma is not None else "negative (no sigma given to explain it)")
            raise DataError(f"sample {i}: value {self.value[i].tolist()} is {what}")
        return self

    # ------------------------------------------------------------------ convenience

    def subset(self, index) -> GonioData:
        """Samples selected by a boolean mask or an index array."""
        idx = np.asarray(index)
        return dataclasses.replace(
            self,
            wi=self.wi[idx],
            wo=self.wo[idx],
            value=self.value[idx],
            weight=self.weight[idx],
            sigma=None if self.sigma is None else self.sigma[idx],
        )

    def subsample(self, n: int, seed: int = 0, how: str = "uniform") -> GonioData:
        """At most ``n`` samples, drawn without replacement, in file order
        (:func:`subsample_index`); all of them when there are no more than ``n``."""
        return self if self.n <= n else self.subset(subsample_index(self, n, seed, how))

    def with_metadata(self, **kw) -> GonioData:
        return dataclasses.replace(self, metadata={**self.metadata, **kw})

    def angles_deg(self) -> dict[str, np.ndarray]:
        """``theta_i, phi_i, theta_o, phi_o`` in degrees (phi in [0, 360))."""
        out = {}
        for name, w in (("i", self.wi), ("o", self.wo)):
            out[f"theta_{name}"] = np.degrees(np.arccos(np.clip(w[:, 2], -1.0, 1.0)))
            out[f"phi_{name}"] = np.mod(np.degrees(np.arctan2(w[:, 1], w[:, 0])), 360.0)
        return out

    @staticmethod
    def from_angles_deg(theta_i, phi_i, theta_o, phi_o, value, **kw) -> GonioData:
        """Build from angles in degrees (``phi`` measured from the tangent x)."""

        def unit(t, p):
            t_deg = np.asarray(t, float)
            t, p = np.radians(t_deg), np.radians(np.asarray(p, float))
            # theta = 90 deg is the horizon: cos exactly 0, not np.cos(pi/2) = 6e-17 (which
            # validate() would accept as above the horizon)
            cos_t = np.where(np.abs(t_deg) == 90.0, 0.0, np.cos(t))
            return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), cos_t], -1)

        return GonioData(wi=unit(theta_i, phi_i), wo=unit(theta_o, phi_o), value=value, **kw)


# ----------------------------------------------------------------------------- subsamples

#: the ways :func:`subsample_index` draws: a simple random sample, or one stratified by the half
#: and difference angles
SUBSAMPLES = ("uniform", "stratified")
#: strata of the stratified subsample: bins of theta_h, equal in sqrt(theta_h / 90 deg) (MERL's
#: theta_h index, Matusik et al. 2003: narrow near the specular peak, where the BRDF changes
#: fastest), and of theta_d, equal in angle
STRATA_THETA_H = 16
STRATA_THETA_D = 8


def half_difference_strata(wi, wo) -> np.ndarray:
    """Stratum of every pair (``0 .. STRATA_THETA_H * STRATA_THETA_D - 1``) by its half angle
    theta_h and difference angle theta_d (Rusinkiewicz 1998: ``h = (wi + wo) / |wi + wo|``,
    ``cos theta_h = h_z``, ``cos theta_d = wi . h``). A pair with ``wi = -wo`` (no half vector)
    falls in the last stratum."""
    wi, wo = np.asarray(wi, float), np.asarray(wo, float)
    h = wi + wo
    norm = np.linalg.norm(h, axis=-1)
    ok = norm > 0
    h = h / np.where(ok, norm, 1.0)[:, None]
    theta_h = np.where(ok, np.arccos(np.clip(h[:, 2], -1.0, 1.0)), np.pi / 2)
    theta_d = np.where(ok, np.arccos(np.clip(np.sum(wi * h, -1), -1.0, 1.0)), np.pi / 2)
    ih = np.floor(np.sqrt(np.clip(theta_h / (np.pi / 2), 0.0, 1.0)) * STRATA_THETA_H)
    idd = np.floor(np.clip(theta_d / (np.pi / 2), 0.0, 1.0) * STRATA_THETA_D)
    ih = np.minimum(ih, STRATA_THETA_H - 1).astype(np.int64)
    idd = np.minimum(idd, STRATA_THETA_D - 1).astype(np.int64)
    return ih * STRATA_THETA_D + idd


def subsample_index(data: GonioData, n: int, seed: int = 0, how: str = "uniform") -> np.ndarray:
    """Sorted indices of ``n`` of ``data``'s samples (``n < data.n``), seeded.

    ``"uniform"``: a simple random sample. ``"stratified"``: a stratified random sample with
    proportional allocation (Cochran, *Sampling Techniques*, 3rd ed., 1977, ch. 5) over the
    strata of :func:`half_difference_strata`: each stratum gets its share ``n N_s / N`` of the
    samples, rounded by largest remainders so that the shares add up to ``n``, drawn uniformly
    inside it. Every sample still stands for ``N / n`` of the data (no weights are needed and the
    fit's objective is the same), but every stratum holding at least ``N / n`` samples is
    represented by its share, where a simple random sample leaves the small strata (the
    specular peak of a MERL file, grazing difference angles) to chance."""
    if how not in SUBSAMPLES:
        raise ValueError(f"subsample {how!r}: expected one of {', '.join(SUBSAMPLES)}")
    N = data.n
    if not 0 < n < N:
        raise ValueError(f"a subsample of {n} of {N} samples: expected 0 < n < {N}")
    rng = np.random.default_rng(seed)
    if how == "uniform":
        return np.sort(rng.choice(N, n, replace=False))
    stratum = half_difference_strata(data.wi, data.wo)
    counts = np.bincount(stratum, minlength=STRATA_THETA_H * STRATA_THETA_D)
    share = counts * (n / N)
    take = np.floor(share).astype(np.int64)
    rest = n - int(take.sum())
    if rest:  # largest remainders first; ties by stratum number (deterministic)
        order = np.argsort(-(share - take), kind="stable")
        take[order[:rest]] += 1
    by_stratum = np.argsort(stratum, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)])
    picked = [by_stratum[starts[s]:starts[s + 1]][rng.choice(counts[s], k, replace=False)]
              for s, k in enumerate(take) if k]
    return np.sort(np.concatenate(picked))
