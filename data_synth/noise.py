"""Noise and calibration models of the virtual gonioreflectometer.

Two kinds of model:

* **direction models** (:class:`AngularJitter`) perturb the arm directions *before* the BRDF is
  evaluated; the dataset records the nominal directions, as a real instrument reports the angles
  it was commanded to, not the ones it reached;
* **value models** (:class:`Lognormal`, :class:`Shot`, :class:`Dark`, :class:`Gain`) act on the
  clean values (N, C) after evaluation, in the order they are listed.

:func:`run_pipeline` applies a list of models in that order: every direction model first (in
list order), then the evaluation, then every value model in list order. Each stage draws from
its own stream, ``numpy.random.SeedSequence(seed).spawn(len(models))[position]``, so a dataset
is a deterministic function of the seed and the list (changing one stage's parameters does not
reshuffle the noise of the others).

Uncertainty estimates: each value model updates a per-sample standard deviation ``sigma``
(None until a stage provides one). Independent additive terms add in quadrature; a
multiplicative stage scales the incoming sigma by its factor. The estimates are computed from the
*noisy* values, as one would from a measurement (first order in the noise). :class:`Gain` is a
systematic error common to a whole channel: it scales sigma but adds nothing to it (an unknown
calibration error is not a per-sample variance), and its drawn factors are recorded in the
``truth`` dict. :class:`AngularJitter` adds no sigma (its effect depends on the BRDF's gradient).

Recipes name the models as ``{type = "lognormal", args = {sigma = 0.01}}``; see :data:`NOISE`
and :func:`make_noise`.
"""

from __future__ import annotations

import dataclasses
import inspect
from typing import Any, ClassVar

import numpy as np

__all__ = [
    "NoiseError",
    "NoiseModel",
    "DirectionNoise",
    "ValueNoise",
    "Lognormal",
    "Shot",
    "Dark",
    "Gain",
    "AngularJitter",
    "NOISE",
    "make_noise",
    "run_pipeline",
]


class NoiseError(ValueError):
    """Invalid noise model name or arguments (the message names the valid choices)."""


def _nonneg(owner: str, name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if not np.isfinite(v) or v < 0:
        raise NoiseError(f"{owner}: {name} must be finite and >= 0, got {value!r}")
    return v


@dataclasses.dataclass(frozen=True)
class NoiseModel:
    """Base class: ``spec()`` gives the JSON-able ``{"type", "args"}`` recipe entry."""

    type_name: ClassVar[str] = ""

    def spec(self) -> dict[str, Any]:
        return {"type": self.type_name, "args": dataclasses.asdict(self)}


@dataclasses.dataclass(frozen=True)
class ValueNoise(NoiseModel):
    """A model acting on values: ``apply(values, sigma, wi, wo, rng, truth)`` returns the new
    ``(values, sigma)``. ``wi``, ``wo`` are the nominal directions; ``truth`` collects drawn
    systematic quantities for the metadata."""

    def apply(self, values, sigma, wi, wo, rng, truth):  # pragma: no cover - abstract
        raise NotImplementedError


@dataclasses.dataclass(frozen=True)
class DirectionNoise(NoiseModel):
    """A model acting on directions before evaluation: ``perturb(wi, wo, rng)``."""

    def perturb(self, wi, wo, rng):  # pragma: no cover - abstract
        raise NotImplementedError


def _quad(*terms):
    """sqrt of the sum of squares of the non-None terms (None if all are None)."""
    terms = [t for t in terms if t is not None]
    if not terms:
        return None
    return np.sqrt(sum(np.square(t) for t in terms))


@dataclasses.dataclass(frozen=True)
class Lognormal(ValueNoise):
    """Multiplicative noise ``v' = v exp(sigma z)``, ``z ~ N(0, 1)`` per sample and channel.

    Median-preserving: ``log(v'/v)`` has mean 0 and standard deviation ``sigma`` (the mean of
    ``v'`` is ``v exp(sigma^2/2)``, a 5e-5 relative bias at 1%). Models source-power and
    speckle fluctuations, which scale with the signal. Sigma estimate: ``sigma |v'|``."""

    sigma: float = 0.01
    type_name: ClassVar[str] = "lognormal"

    def __post_init__(self):
        object.__setattr__(self, "sigma", _nonneg("lognormal", "sigma", self.sigma))

    def apply(self, values, sigma, wi, wo, rng, truth):
        f = np.exp(self.sigma * rng.standard_normal(values.shape))
        v = values * f
        return v, _quad(None if sigma is None else sigma * f, self.sigma * np.abs(v))


@dataclasses.dataclass(frozen=True)
class Shot(ValueNoise):
    """Photon (shot) noise: the detector counts ``n ~ Poisson(v cos(theta_o) photons_per_unit)``
    and reports ``v' = n / (cos(theta_o) photons_per_unit)``.

    The ``cos(theta_o)`` is the detected flux of an under-filled beam (a beam footprint inside
    the sample): the flux reaching a detector of fixed solid angle is proportional to
    ``f_r cos(theta_o)`` times the beam power, so grazing views collect fewer photons and are
    noisier. Negative inputs (after a :class:`Dark` stage) count as 0. Sigma estimate:
    ``sqrt(max(n, 1)) / (cos(theta_o) photons_per_unit)`` (a zero count still has an
    uncertainty of about one photon)."""

    photons_per_unit: float = 1e4
    type_name: ClassVar[str] = "shot"

    def __post_init__(self):
        v = _nonneg("shot", "photons_per_unit", self.photons_per_unit)
        if v == 0:
            raise NoiseError("shot: photons_per_unit must be > 0")
        object.__setattr__(self, "photons_per_unit", v)

    def apply(self, values, sigma, wi, wo, rng, truth):
        scale = (np.maximum(wo[:, 2], 0.0) * self.photons_per_unit)[:, None]
        lam = np.maximum(values, 0.0) * scale
        counts = rng.poisson(lam).astype(np.float64)
        safe = np.where(scale > 0, scale, 1.0)
        v = np.where(scale > 0, counts / safe, 0.0)
        return v, _quad(sigma, np.sqrt(np.maximum(counts, 1.0)) / safe)


@dataclasses.dataclass(frozen=True)
class Dark(ValueNoise):
    """Additive Gaussian noise ``v' = v + sigma z`` (detector dark current and read-out noise,
    in BRDF units, 1/sr); values may become slightly negative, as measured ones do. Sigma
    estimate: ``sigma``."""

    sigma: float = 1e-3
    type_name: ClassVar[str] = "dark"

    def __post_init__(self):
        object.__setattr__(self, "sigma", _nonneg("dark", "sigma", self.sigma))

    def apply(self, values, sigma, wi, wo, rng, truth):
        v = values + self.sigma * rng.standard_normal(values.shape)
        return v, _quad(sigma, np.full_like(v, self.sigma))


@dataclasses.dataclass(frozen=True)
class Gain(ValueNoise):
    """Per-channel calibration error: one factor ``g_c = exp(sigma z_c)`` per channel, drawn once
    per dataset and applied to every sample (``v' = v g``). Recorded in ``truth["gain"]``; it
    scales an incoming sigma but adds none (see the module docstring)."""

    sigma: float = 0.02
    type_name: ClassVar[str] = "gain"

    def __post_init__(self):
        object.__setattr__(self, "sigma", _nonneg("gain", "sigma", self.sigma))

    def apply(self, values, sigma, wi, wo, rng, truth):
        g = np.exp(self.sigma * rng.standard_normal(values.shape[1]))
        prev = truth.get("gain")
        truth["gain"] = (g if prev is None else np.asarray(prev) * g).tolist()
        return values * g, None if sigma is None else sigma * g


@dataclasses.dataclass(frozen=True)
class AngularJitter(DirectionNoise):
    """Pointing error of the arms: each of ``wi`` and ``wo`` is rotated, independently per
    sample, by a random tangent vector ``delta = sigma (z1 t1 + z2 t2)`` (``t1``, ``t2`` an
    orthonormal tangent basis at the direction, ``z ~ N(0, 1)``), i.e.
    ``w' = cos|delta| w + sin|delta| delta/|delta|``: an isotropic angular error with standard
    deviation ``sigma_deg`` per axis. A direction pushed below the horizon is reflected back
    above it (``z -> |z|``). The model sees the jittered directions, the dataset the nominal ones.
    """

    sigma_deg: float = 0.1
    type_name: ClassVar[str] = "angular_jitter"

    def __post_init__(self):
        object.__setattr__(self, "sigma_deg", _nonneg("angular_jitter", "sigma_deg",
                                                      self.sigma_deg))

    @staticmethod
    def _tangents(w):
        # any vector not parallel to w, then Gram-Schmidt
        a = np.where(np.abs(w[:, 2:3]) < 0.9, np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))
        t1 = np.cross(a, w)
        t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
        t2 = np.cross(w, t1)
        return t1, t2

    def _one(self, w, rng):
        z = rng.standard_normal((w.shape[0], 2)) * np.radians(self.sigma_deg)
        t1, t2 = self._tangents(w)
        delta = z[:, :1] * t1 + z[:, 1:] * t2
        ang = np.linalg.norm(delta, axis=-1, keepdims=True)
        safe = np.where(ang > 0, ang, 1.0)
        out = np.cos(ang) * w + np.sin(ang) * delta / safe
        out[:, 2] = np.abs(out[:, 2])
        return out / np.linalg.norm(out, axis=-1, keepdims=True)

    def perturb(self, wi, wo, rng):
        return self._one(wi, rng), self._one(wo, rng)


NOISE: dict[str, type[NoiseModel]] = {
    "lognormal": Lognormal,
    "shot": Shot,
    "dark": Dark,
    "gain": Gain,
    "angular_jitter": AngularJitter,
}
_NOISE_ALIASES = {"jitter": "angular_jitter", "poisson": "shot", "multiplicative": "lognormal",
                  "additive": "dark"}


def make_noise(spec) -> NoiseModel:
    """A noise model from a model instance or a recipe entry ``{"type": name, "args": {...}}``
    (the arguments may also sit beside ``type``). Unknown types or arguments raise
    :class:`NoiseError` listing the valid ones."""
    if isinstance(spec, NoiseModel):
        return spec
    if not isinstance(spec, dict) or "type" not in spec:
        raise NoiseError(f"a noise entry must be a table/dict with a 'type' key, got {spec!r}; "
                         f"valid types: {', '.join(NOISE)}")
    name = str(spec["type"]).strip().lower().replace("-", "_")
    name = _NOISE_ALIASES.get(name, name)
    if name not in NOISE:
        raise NoiseError(f"unknown noise type {spec['type']!r}; valid types: {', '.join(NOISE)}")
    cls = NOISE[name]
    if not isinstance(spec.get("args", {}), dict):
        raise NoiseError(f"noise {name!r}: 'args' must be a table/dict of arguments, got "
                         f"{spec['args']!r}")
    args = dict(spec.get("args", {}))
    args.update({k: v for k, v in spec.items() if k not in ("type", "args")})
    valid = list(inspect.signature(cls).parameters)
    unknown = [a for a in args if a not in valid]
    if unknown:
        raise NoiseError(f"noise {name!r}: unknown argument(s) {', '.join(map(repr, unknown))}; "
                         f"valid arguments: {', '.join(valid)}")
    return cls(**args)


def run_pipeline(models, wi, wo, evaluate, seed: int):
    """Apply ``models`` (see the module docstring for the order) around ``evaluate(wi, wo) ->
    (N, C) clean values``, where ``wi``, ``wo`` are the nominal directions. Returns
    ``(clean, values, sigma, truth)``: the noise-free values at the directions the instrument
    actually reached (the nominal ones without :class:`AngularJitter`), the noisy values, the
    per-sample sigma estimate (or None) and the drawn systematic quantities."""
    models = [make_noise(m) for m in models]
    streams = [np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(
        len(models))]
    wi_eff, wo_eff = wi, wo
    for m, rng in zip(models, streams, strict=True):
        if isinstance(m, DirectionNoise):
            wi_eff, wo_eff = m.perturb(wi_eff, wo_eff, rng)
    clean = evaluate(wi_eff, wo_eff)
    values, sigma, truth = clean, None, {}
    for m, rng in zip(models, streams, strict=True):
        if isinstance(m, ValueNoise):
            values, sigma = m.apply(values, sigma, wi, wo, rng, truth)
    return clean, values, sigma, truth
