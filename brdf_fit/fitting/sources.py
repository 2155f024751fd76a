"""Where a fit's parameters come from: a registry entry's flat, named parameters or a built
model's floating-point leaves (:class:`ModelSource`, made by :func:`model_source`), and
which of them are free (:func:`resolve_free`). :mod:`brdf_fit.fitting.problem`
re-exports these names.

**Where the parameters come from** (:class:`ModelSource`, made by :func:`model_source`):

- a *registry* name or :class:`~brdf_fit.core.params.Entry` (:class:`RegistrySource`): the entry's
  flat, named parameters with their registry intervals; ``build`` is ``entry.build(**params)``;
- any *built* model, an :class:`~brdf_fit.models.AbstractBRDF` pytree, composed or not
  (:class:`TemplateSource`): its floating-point fields, found by walking the equinox modules
  (tuples of modules included), each named by its attribute path (``distribution.alpha_x``,
  ``fresnel.f0``, ``lobes.1.distribution.alpha_x`` for a :class:`~brdf_fit.models.Mixture`'s
  tuple). A field is a parameter when its value is a Python float, a floating-point array or a
  list/tuple of numbers (converted to an array), or any number when the field declares an
  interval (:func:`~brdf_fit.core.params.bounded`). ``None`` (an isotropic GGX's ``alpha_y``),
  static fields, integers and strings are not parameters; they stay as in the template.
  ``build`` puts values back with :func:`equinox.tree_at`, so a fitted model has the template's
  structure. The interval of a leaf is the one its component declares
  (:func:`~brdf_fit.core.params.declared_interval`) unless ``bounds=`` overrides it; **a leaf
  without a declared interval and without ``bounds=`` is fitted unbounded** (the identity
  transform). That choice keeps every built model fittable while components gain their
  declarations; where an unbounded leaf can leave the model's valid range (a roughness below
  0), pass ``bounds={"path": (lo, hi)}`` or leave it out of ``free=``. A leaf is a channel
  parameter (one tangent and one design dimension for all its channels, see
  :mod:`brdf_fit.fitting._lm`) only where its component declares ``channels=True`` and its
  value is a vector; an undeclared vector leaf is treated entry by entry, which is always
  correct, only slower, and a scalar value of a channel field is shared by all channels.
  Template values keep their shapes (an RGB ``f0`` keeps its channel axis, a scalar one stays
  scalar: the built model is the model that is fitted).
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit import registry
from brdf_fit.core.params import Entry, Interval, declared_interval
from brdf_fit.core.validate import FitError, ParameterError
from brdf_fit.fitting.transforms import Transform

__all__ = [
    "ParamSpec", "ModelSource", "RegistrySource", "TemplateSource", "model_source", "resolve_free",
    "check_choice",
]

@dataclasses.dataclass(frozen=True, eq=False)
class ParamSpec:
    """One parameter a fit may vary: its name (registry name or attribute path), the transform
    of its interval, whether it is a channel parameter, its default (the registry default, or
    the template's value) and, for a template leaf, its fixed shape (None: a registry
    parameter, whose shape follows the data's channel count)."""

    name: str
    transform: Transform
    channels: bool
    default: np.ndarray
    shape: tuple[int, ...] | None = None
    #: ``check(value, owner)``: raise if a concrete value is invalid for this parameter
    check: Callable[[Any, str], None] | None = None

    def start_value(self, v, n_channels: int) -> np.ndarray:
        """A start or fixed value of :func:`~brdf_fit.fitting.single.fit`: a template leaf
        broadcast to its shape; a registry channel parameter broadcast to the data's channels
        (a scalar) or replaced by its mean (a vector of another length)."""
        v = np.asarray(v, float)
        if self.shape is not None:
            return self._broadcast(v, self.shape)
        C = n_channels
        if self.channels and v.ndim == 0 and C > 1:
            v = np.full(C, float(v))
        elif self.channels and v.ndim == 1 and v.shape[0] != C and C >= 1:
            v = np.full(C, float(np.mean(v)))
        return v

    def batched_value(self, v, B: int, n_channels: int, what: str) -> np.ndarray:
        """Per-problem values (B, ...) for :func:`~brdf_fit.fitting.batch.fit_batch` from a
        value shared by all problems or given per problem (one more leading axis of B rows): a
        registry channel parameter scalar or (C,) shared, (B, C) per problem; a registry scalar
        parameter scalar shared, (B,) per problem; a template leaf of shape S: S (or
        broadcastable) shared, (B, *S) per problem."""
        a = np.asarray(v, float)
        C = n_channels
        if self.shape is not None:
            per = a.ndim == len(self.shape) + 1
            if per and a.shape[0] != B:
                raise FitError(f"{what}[{self.name!r}] has {a.shape[0]} rows for {B} problems")
            if per:
                return np.ascontiguousarray(np.stack([self._broadcast(r, self.shape)
                                                      for r in a]))
            return np.ascontiguousarray(np.broadcast_to(self._broadcast(a, self.shape),
                                                        (B, *self.shape)))
        per = (a.ndim == 2) if self.channels else (a.ndim == 1)
        if per:
            if a.shape[0] != B:
                raise FitError(f"{what}[{self.name!r}] has {a.shape[0]} rows for {B} problems")
            if self.channels and a.shape[1] != C:
                a = np.repeat(a.mean(axis=1, keepdims=True), C, axis=1)
        else:
            if self.channels:
                a = np.full(C, float(a)) if a.ndim == 0 else a
                if a.shape[0] != C:
                    a = np.full(C, float(np.mean(a)))
            a = np.broadcast_to(a, (B, *a.shape))
        return np.ascontiguousarray(a)

    def _broadcast(self, v, shape):
        try:
            return np.array(np.broadcast_to(v, shape), float)
        except ValueError:
            raise FitError(f"parameter {self.name!r} has shape {shape} in the model; got a "
                           f"value of shape {np.shape(v)}") from None


class ModelSource:
    """Where a fit's model and its parameters come from (see the module docstring):
    :class:`RegistrySource` or :class:`TemplateSource`. ``params`` lists every parameter
    (:class:`ParamSpec`) in order; ``build(params)`` makes the model from ``{name: value}``
    (missing names take their defaults); ``key`` is hashable and equal for two sources whose
    ``build`` is the same function of the parameters (compiled solvers are cached on it)."""

    name: str
    params: tuple[ParamSpec, ...]
    key: Any
    #: check name -> reason, for checks the model is not meant to pass (registry entries)
    expected_failures: Mapping[str, str]
    #: whether a channel's output depends on other channels' entries of a channel parameter
    #: (e.g. glTF's max over the Fresnel colour): then no parameter is taken channel by
    #: channel (:meth:`ParamLayout.structured`, :meth:`ParamLayout.channel_index`)
    coupled: bool = False

    @functools.cached_property
    def _by_name(self) -> dict[str, ParamSpec]:
        return {p.name: p for p in self.params}

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params)

    def param(self, name: str) -> ParamSpec:
        """The parameter called ``name``; an unknown name raises with the valid list."""
        p = self._by_name.get(name)
        if p is None:
            self.unknown(name)
        return p

    def match(self, name: str) -> tuple[str, ...]:
        """The parameters ``name`` selects in ``free=`` (itself; see subclasses)."""
        return (self.param(name).name,)

    def unknown(self, name: str):  # pragma: no cover - overridden
        raise FitError(f"{self.name}: unknown parameter {name!r}")

    def defaults(self) -> dict[str, np.ndarray]:
        return {p.name: p.default for p in self.params}

    def build(self, params: Mapping[str, Any]):  # pragma: no cover - overridden
        raise NotImplementedError


class RegistrySource(ModelSource):
    """The parameters of a registry entry (its flat names, registry intervals and channels)."""

    def __init__(self, entry: Entry):
        self.entry = entry
        self.name = entry.name
        self.key = ("registry", entry.name)
        self.expected_failures = entry.expected_failures
        self.coupled = bool(entry.channels_coupled)
        self.params = tuple(
            ParamSpec(p.name, Transform.of(p), bool(p.channels), p.default_value(), None,
                      p.validate)
            for p in entry.params)

    def param(self, name: str) -> ParamSpec:
        self.entry.param(name)  # unknown names raise ParameterError with the valid list
        return super().param(name)

    def build(self, params):
        return self.entry.build(**params)


def _is_number(x) -> bool:
    return isinstance(x, int | float | np.integer | np.floating) and not isinstance(x, bool)


def _as_float_array(value, declared: bool):
    """The value of a parameter leaf as a float array, or None if ``value`` is not one (see
    the module docstring): floats, floating arrays and lists of numbers; any number where the
    field declares an interval."""
    if value is None or isinstance(value, bool | str):
        return None
    if isinstance(value, float | np.floating):
        return np.asarray(value, float)
    if isinstance(value, int | np.integer):
        return np.asarray(value, float) if declared else None
    if isinstance(value, list | tuple):
        if value and all(_is_number(x) for x in value):
            a = np.asarray(value)
            return a.astype(float) if (declared or a.dtype.kind == "f") else None
        return None
    if isinstance(value, jax.Array | np.ndarray):
        kind = np.dtype(value.dtype).kind
        if kind == "f" or (declared and kind in "iu"):
            return np.asarray(value, float)
    return None


@dataclasses.dataclass(frozen=True)
class _Leaf:
    path: tuple[str | int, ...]
    owner: str  # the component's class name
    interval: Interval | None
    channels: bool
    value: np.ndarray


def _walk(obj, path=()) -> Iterable[_Leaf]:
    """The parameter leaves of a model (see the module docstring), depth first in field order."""
    for f in dataclasses.fields(obj):
        if f.metadata.get("static", False):
            continue
        v = getattr(obj, f.name, None)
        p = (*path, f.name)
        interval = declared_interval(obj, f.name)
        if isinstance(v, eqx.Module):
            yield from _walk(v, p)
            continue
        if isinstance(v, list | tuple) and any(isinstance(x, eqx.Module) for x in v):
            for i, x in enumerate(v):
                if isinstance(x, eqx.Module):
                    yield from _walk(x, (*p, i))
            continue
        a = _as_float_array(v, interval is not None)
        if a is not None:
            # a scalar value of a channel field is one value for every channel: shared
            chan = bool(f.metadata.get("channels", False)) and a.ndim == 1
            yield _Leaf(p, type(obj).__name__, interval, chan, a)


def _path_name(path) -> str:
    return ".".join(str(k) for k in path)


def _get(node, path):
    for k in path:
        node = node[k] if isinstance(k, int) else getattr(node, k)
    return node


def _hashable(leaf):
    if isinstance(leaf, jax.Array | np.ndarray):
        a = np.asarray(leaf)
        return ("array", a.shape, str(a.dtype), a.tobytes())
    try:
        hash(leaf)
    except TypeError:
        return ("id", id(leaf))
    return leaf


def _checker(interval, owner, name):
    """``check(value, model_name)`` of a template leaf: a concrete value outside the leaf's
    interval raises :class:`FitError`."""
    def check(value, model_name):
        if interval is not None:
            try:
                interval.check(name, value, owner=f"{model_name} ({owner})")
            except ParameterError as e:
                raise FitError(str(e)) from None
    return check


class _Slot:
    """Stands for a parameter leaf in a template's cache key (every slot compares equal)."""

    def __eq__(self, other):
        return isinstance(other, _Slot)

    def __hash__(self):
        return hash(_Slot)


class TemplateSource(ModelSource):
    """The floating-point leaves of a built model, keyed by attribute path (see the module
    docstring). ``bounds``: ``{path: (lo, hi)}`` (either end None: unbounded that side)
    overriding a declared interval, or giving one where none is declared."""

    def __init__(self, template, bounds: Mapping[str, Any] | None = None):
        if not isinstance(template, eqx.Module):
            raise FitError(f"a fit takes a registry name or a built model (an equinox "
                           f"module), got {type(template).__name__}")
        self.template = template
        self.name = type(template).__name__
        leaves = list(_walk(template))
        self._paths = tuple(leaf.path for leaf in leaves)
        names = [_path_name(p) for p in self._paths]
        bounds = dict(bounds or {})
        specs = []
        for leaf, name in zip(leaves, names, strict=True):
            interval = leaf.interval
            if name in bounds:
                lo, hi = bounds[name]
                interval = Interval(None if lo is None else float(lo),
                                    None if hi is None else float(hi))
            specs.append(ParamSpec(name, Transform.of(interval), leaf.channels, leaf.value,
                                   leaf.value.shape, _checker(interval, leaf.owner, name)))
        self.params = tuple(specs)
        self.expected_failures = {}
        for k in bounds:
            if k not in names:
                self.unknown(k, "bounds")
        skeleton = self._replace(template, tuple(_Slot() for _ in self._paths))
        self.key = ("template", jax.tree.structure(skeleton),
                    tuple(_hashable(x) for x in jax.tree.leaves(skeleton)))

    def _replace(self, model, values):
        if not self._paths:
            return model
        paths = self._paths
        return eqx.tree_at(lambda m: tuple(_get(m, p) for p in paths), model, replace=values)

    def build(self, params):
        """The template with every parameter leaf replaced by ``params[name]`` (its template
        value, as an array, where absent)."""
        values = tuple(params[p.name] if p.name in params else jnp.asarray(p.default)
                       for p in self.params)
        return self._replace(self.template, values)

    def match(self, name: str) -> tuple[str, ...]:
        """``free=`` entries select a parameter by its path, or every parameter under a
        component path (``"distribution"``: ``distribution.alpha_x``, ...)."""
        if name in self._by_name:
            return (name,)
        under = tuple(n for n in self.names if n.startswith(name + "."))
        if under:
            return under
        self.unknown(name)

    def unknown(self, name: str, what: str = "parameter"):
        valid = ", ".join(self.names) or "(none)"
        try:
            v = _get(self.template, tuple(int(k) if k.isdigit() else k
                                          for k in str(name).split(".")))
        except (AttributeError, IndexError, TypeError, KeyError):
            close = difflib.get_close_matches(str(name), self.names, n=3)
            why = " (no such attribute path" + (
                f"; did you mean {', '.join(close)}?)" if close else ")")
        else:
            kind = "None" if v is None else type(v).__name__
            why = f" (the model has {kind} there, not a floating-point parameter)"
        raise FitError(f"{self.name}: unknown {what} {name!r}{why}; valid parameters: {valid}. "
                       "Name parameters by attribute path in free=, fix=, init= and bounds=.")


def check_choice(kind: str, value, valid, label: str | None = None) -> None:
    """Raise :class:`FitError` ``unknown KIND 'VALUE'; LABEL: a, b, c`` unless ``value`` is one
    of ``valid`` (``label`` defaults to ``valid KINDs``): the one form fit, fit_batch and
    FitProblem.of refuse an option in, before any work."""
    if value not in valid:
        raise FitError(f"unknown {kind} {value!r}; {label or f'valid {kind}s'}: "
                       f"{', '.join(valid)}")


def model_source(model, bounds: Mapping[str, Any] | None = None) -> ModelSource:
    """The :class:`ModelSource` of a registry name, a registry
    :class:`~brdf_fit.core.params.Entry`, a built model (:class:`TemplateSource`) or a source
    itself. ``bounds`` applies to built models only (registry parameters keep their registry
    intervals)."""
    if isinstance(model, ModelSource):
        src = model
    elif isinstance(model, str | Entry):
        entry = registry.get(model) if isinstance(model, str) else model
        if "delta" in entry.tags:
            raise FitError(f"{entry.name} is a delta lobe: its BRDF is 0 at every pair of "
                           "directions a gonioreflectometer samples (only the exact mirror "
                           "direction reflects), so there is nothing to fit")
        src = RegistrySource(entry)
    elif isinstance(model, eqx.Module):  # an AbstractBRDF, or any module with eval()
        if getattr(model, "is_delta", False):
            raise FitError(f"{type(model).__name__} is a delta lobe: its BRDF is 0 at every "
                           "sampled pair of directions, so there is nothing to fit")
        return TemplateSource(model, bounds)
    else:
        raise FitError(f"a fit takes a registry name or a built model (an AbstractBRDF), got "
                       f"{type(model).__name__}")
    if bounds:
        raise FitError("bounds= applies to built models; registry parameters keep their "
                       "registry intervals (fit the built model instead)")
    return src


def resolve_free(source: ModelSource, fix: Mapping | None = None, init: Mapping | None = None,
                 free: Iterable[str] | None = None) -> tuple[str, ...]:
    """The free parameters, in the source's order: every parameter not in ``fix`` (default), or
    those ``free`` selects (:meth:`ModelSource.match`). Every name in ``fix``, ``init`` and
    ``free`` is checked (an unknown one raises with the valid list); a parameter both fixed
    and named in ``free`` is an error."""
    fix, init = dict(fix or {}), dict(init or {})
    for k in (*fix, *init):
        source.param(k)
    if free is None:
        chosen = set(source.names)
    else:
        if isinstance(free, str):
            free = (free,)
        chosen = set()
        for k in free:
            chosen.update(source.match(k))
        both = sorted(chosen & set(fix))
        if both:
            raise FitError(f"{source.name}: {', '.join(both)} both fixed (fix=) and free (free=)")
    return tuple(n for n in source.names if n in chosen and n not in fix)
