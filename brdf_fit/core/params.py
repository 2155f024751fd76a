"""What models and the registry declare about a model: its parameters (:class:`Param`: default,
valid interval, channels) and its registry entry (:class:`Entry`: builder, reference, declared
check outcomes).

This is a bottom-layer module: model modules import it to declare their own entries, and
:mod:`brdf_fit.registry` collects those entries; neither direction needs the other's code.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float

from brdf_fit.core.validate import ParameterError, PrecisionWarning, check_param, concrete

__all__ = [
    "node_input_values",
    "node_param",
    "Param",
    "Entry",
    "UnknownModelError",
    "Interval",
    "bounded",
    "declared_interval",
    "Scalar",
    "Channels",
]

#: Annotation of a scalar parameter (geometric ones: widths, exponents, angles).
Scalar = Float[ArrayLike, ""]
#: Annotation of a colour parameter: a scalar or a trailing channel axis (RGB or wavelengths).
Channels = Float[ArrayLike, "*channels"]


@dataclass(frozen=True)
class Interval:
    """The valid interval of a parameter: ``[lo, hi]`` with ends open as flagged (None: unbounded
    on that side)."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False

    def __str__(self) -> str:
        lo = "-inf" if self.lo is None else f"{self.lo:g}"
        hi = "inf" if self.hi is None else f"{self.hi:g}"
        lb = "(" if (self.lo_open or self.lo is None) else "["
        rb = ")" if (self.hi_open or self.hi is None) else "]"
        return f"{lb}{lo}, {hi}{rb}"

    def check(self, name, value, owner: str | None = None) -> None:
        """Raise :class:`ParameterError` if a concrete ``value`` leaves the interval."""
        check_param(name, value, self.lo, self.hi, self.lo_open, self.hi_open, owner=owner)


#: the field-metadata key under which a model component declares a parameter's interval
INTERVAL_KEY = "interval"


def bounded(default=dataclasses.MISSING, *, lo=None, hi=None, lo_open=False, hi_open=False,
            channels: bool = False, **kwargs):
    """An ``equinox`` field that declares its valid interval (and whether it may carry a
    trailing channel axis) in its metadata. :func:`declared_interval` reads it back; fitting a
    built model (:func:`brdf_fit.fit`) maps each free leaf through its interval.

    ``alpha_x: Float[Array, ""] = bounded(0.3, lo=0.0, hi=1.0, lo_open=True)``."""
    meta = dict(kwargs.pop("metadata", {}) or {})
    meta[INTERVAL_KEY] = Interval(lo, hi, lo_open, hi_open)
    meta["channels"] = channels
    if default is not dataclasses.MISSING:
        kwargs["default"] = default
    return eqx.field(metadata=meta, **kwargs)


def declared_interval(module, field_name: str) -> Interval | None:
    """The :class:`Interval` a component declares for ``field_name`` (None: none declared)."""
    for f in dataclasses.fields(module):
        if f.name == field_name:
            return f.metadata.get(INTERVAL_KEY)
    raise AttributeError(f"{type(module).__name__} has no field {field_name!r}")


class UnknownModelError(KeyError):
    """No registry entry has this name or alias."""

    def __str__(self):  # KeyError quotes its message; keep it readable
        return str(self.args[0])


@dataclass(frozen=True)
class Param:
    """A model parameter: default, valid interval, whether it may carry channels."""

    name: str
    default: Any
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    channels: bool = False
    doc: str = ""
    #: the models evaluate ``max(value, clamp_below)`` (e.g. a microfacet width below
    #: ``ALPHA_MIN``); a concrete value below it is valid, and :meth:`validate` warns
    #: (:class:`~brdf_fit.core.validate.PrecisionWarning`) that it is evaluated at the clamp
    clamp_below: float | None = None

    def default_value(self):
        v = self.default() if callable(self.default) else self.default
        return np.asarray(v, dtype=float)

    def interval(self) -> str:
        return str(Interval(self.lo, self.hi, self.lo_open, self.hi_open))

    def validate(self, value, entry_name: str):
        v = concrete(value)
        if v is not None and v.dtype != object:
            if v.ndim > 1 or (v.ndim == 1 and not self.channels):
                what = "a scalar or a 1-D channel vector" if self.channels else "a scalar"
                raise ParameterError(
                    f"{entry_name}: parameter {self.name!r} must be {what}, got shape {v.shape}"
                )
        check_param(
            self.name, value, self.lo, self.hi, self.lo_open, self.hi_open, owner=entry_name
        )
        if (self.clamp_below is not None and v is not None and v.dtype != object and v.size
                and float(np.min(v)) < self.clamp_below):
            warnings.warn(PrecisionWarning(
                f"{entry_name}: {self.name} = {float(np.min(v)):.3g} is below "
                f"{self.clamp_below:g}: the model evaluates it at {self.clamp_below:g} (the "
                "clamp that keeps D, Lambda and their gradients finite; brdf_fit.core.numerics"
                ".ALPHA_MIN)"), stacklevel=4)


@dataclass(frozen=True)
class Entry:
    """A registered model: ``build(**params)`` returns a model (an
    :class:`~brdf_fit.models.AbstractBRDF`)."""

    name: str
    builder: Callable[..., Any]  # returns an AbstractBRDF
    params: tuple[Param, ...]
    reference: str
    description: str
    aliases: tuple[str, ...] = ()
    #: check name -> reason, for checks this model is not meant to pass (shown, never hidden)
    expected_failures: dict[str, str] = field(default_factory=dict)
    tags: tuple[str, ...] = ()
    #: publication year of the model (the catalogue table's "year" column)
    year: int | None = None
    #: the row of the Montes & Urena (2012) overview table this entry implements (None: not a row,
    #: e.g. a variant); several entries may implement one row (the catalogue shows each)
    catalogue: str | None = None
    #: how ``sample`` draws directions, in a few words ("exact half-vector", "cosine fallback")
    sampler: str = ""
    #: the renderer or format whose own model this entry transcribes ("mitsuba", "gltf"; None:
    #: a model of the literature): a fit in it exports to that target with no loss
    target: str | None = None
    #: for a native entry: ``params -> the target's description`` (a Mitsuba scene dict, a glTF
    #: material), parameter for parameter, so that the export is the fitted model itself
    native_export: Callable[[dict], Any] | None = None
    #: non-empty (the reason) when a channel's value depends on other channels' entries of a
    #: channel parameter (glTF's max over the Fresnel colour, a tint by luminance): fitting
    #: then takes every channel parameter entry by entry (brdf_fit.fitting.problem)
    channels_coupled: str = ""
    #: the fewest starts selection fits this entry from (0: the selector's own rule,
    #: brdf_fit.selection.selector.LAYERED_STARTS for a layered entry): an entry whose fits
    #: stop in local minima from the selector's starts says how many it needs, measured
    select_starts: int = 0

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params)

    def param(self, name: str) -> Param:
        for p in self.params:
            if p.name == name:
                return p
        raise ParameterError(
            f"{self.name}: unknown parameter {name!r}; valid parameters: "
            f"{', '.join(self.param_names) or '(none)'}"
        )

    def defaults(self) -> dict[str, np.ndarray]:
        return {p.name: p.default_value() for p in self.params}

    def build(self, **params):
        """Model with the given parameters; unspecified ones take their defaults. Concrete values
        are validated (unknown name, wrong shape, out of range: :class:`ParameterError`)."""
        for k in params:
            self.param(k)  # raises with the list of valid names
        values = {}
        for p in self.params:
            v = params[p.name] if p.name in params else p.default_value()
            p.validate(v, self.name)
            values[p.name] = jnp.asarray(v)
        return self.builder(**values)

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "aliases": list(self.aliases),
            "description": self.description,
            "reference": self.reference,
            "tags": list(self.tags),
            "year": self.year,
            "catalogue": self.catalogue,
            "sampler": self.sampler,
            "params": [
                {
                    "name": p.name,
                    "default": p.default_value().tolist(),
                    "interval": p.interval(),
                    "channels": p.channels,
                    "doc": p.doc,
                }
                for p in self.params
            ],
            "expected_failures": dict(self.expected_failures),
            "target": self.target,
        }


def node_param(name: str, spec: tuple, default) -> Param:
    """A native entry's registry parameter from ``spec = (doc, channels, lo, hi)`` and the
    node's default (a grey default repeated over RGB for a channel parameter): the Blender and
    OpenPBR entries' shared constructor."""
    doc, channels, lo, hi = spec
    if channels:
        default = (default, default, default)
    return Param(name, default, lo=lo, hi=hi, channels=channels, doc=doc)


def node_input_values(params: dict, valid: tuple[str, ...], colours: tuple[str, ...],
                      node: str) -> dict:
    """A native entry's parameters as a renderer node's input values: ``{name: float}`` for a
    scalar, ``{name: [r, g, b]}`` for a colour (a grey value repeated), every given parameter.
    A name not in ``valid``, or a value of the wrong size, is a ``ValueError`` naming ``node``
    (the Blender and OpenPBR exports' shared conversion)."""
    out = {}
    for name, value in params.items():
        if name not in valid:
            raise ValueError(f"{name!r} is not an input of {node} here; valid: "
                             f"{', '.join(valid)}")
        v = [float(x) for x in np.ravel(np.asarray(value, np.float64))]
        if name in colours:
            if len(v) == 1:
                v = v * 3
            if len(v) != 3:
                raise ValueError(f"{name} must be RGB or grey, got {len(v)} values")
            out[name] = v
        else:
            if len(v) != 1:
                raise ValueError(f"{name} must be a scalar, got {len(v)} values")
            out[name] = v[0]
    return out
