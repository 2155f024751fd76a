"""The fitting problem: which parameters a fit varies, how they map to the solver's flat
unconstrained vector, and the residual of the model they build. :func:`brdf_fit.fitting.single.fit`,
:func:`brdf_fit.fitting.batch.fit_batch` and :mod:`brdf_fit.fitting.guess` all work on a
:class:`FitProblem`.

**The flat layout** (:class:`ParamLayout`): the free parameters, in order, each raveled into the
flat vector ``u`` at its :attr:`~ParamLayout.slices`; the physical value is ``transform.forward``
of its slice (:class:`Transform`). Every split, join, inverse, channel index and mask of the
flat vector goes through this one layout.

The parts it is made of, each a module of its own and re-exported here: where the parameters
come from (:mod:`brdf_fit.fitting.sources`), their transforms (:mod:`brdf_fit.fitting.transforms`),
the residual metrics (:mod:`brdf_fit.fitting.metrics`), and which entries the data determine
(:mod:`brdf_fit.fitting.identifiability`).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Iterable, Mapping

import jax.numpy as jnp
import numpy as np

from brdf_fit.core.validate import FitError
from brdf_fit.fitting.identifiability import (
    DEAD_COLUMN_REL,
    NULL_SHARE,
    RANK_RCOND,
    STDERR_NOTES,
    UNDETERMINED_REL_STDERR,
    UNDETERMINED_RULE,
    entry_labels,
    parameter_entries,
    stderr_codes,
    stderr_notes,
    undetermined,
)
from brdf_fit.fitting.metrics import (
    DATA_SCALE_FLOOR,
    METRIC_H,
    METRICS,
    RELATIVE_FLOOR,
    ROBUST,
    ROBUST_SCALE,
    SIGMA_FLOOR,
    metric_parts,
    robust_residual,
)
from brdf_fit.fitting.sources import (
    ModelSource,
    ParamSpec,
    RegistrySource,
    TemplateSource,
    check_choice,
    model_source,
    resolve_free,
)
from brdf_fit.fitting.transforms import AT_BOUND_REL, EDGE, Transform, at_bound

__all__ = [
    "FitProblem", "ParamLayout", "ParamSpec", "ModelSource", "RegistrySource", "TemplateSource",
    "model_source", "resolve_free", "check_choice", "Transform", "FitError", "at_bound",
    "metric_parts", "robust_residual", "ROBUST", "ROBUST_SCALE",
    "METRICS", "METRIC_H", "RELATIVE_FLOOR", "DATA_SCALE_FLOOR", "EDGE", "AT_BOUND_REL",
    "RANK_RCOND", "DEAD_COLUMN_REL", "NULL_SHARE", "STDERR_NOTES", "stderr_codes", "stderr_notes",
    "UNDETERMINED_REL_STDERR", "UNDETERMINED_RULE", "undetermined", "entry_labels",
    "parameter_entries", "SIGMA_FLOOR",
]


# ----------------------------------------------------------------------------- layout


@dataclasses.dataclass(frozen=True)
class ParamLayout:
    """The flat parameter vector: the free parameters ``names`` in order, each of shape
    ``shapes[i]`` raveled at ``slices[i]``, its physical value ``transforms[i].forward`` of the
    slice; ``channels[i]``: a declared channel parameter. Hashable (part of the compiled
    solvers' cache key). Every method takes leading batch axes."""

    names: tuple[str, ...]
    shapes: tuple[tuple[int, ...], ...]
    transforms: tuple[Transform, ...]
    channels: tuple[bool, ...]
    #: the model couples its channels (:attr:`ModelSource.coupled`): every parameter is
    #: taken entry by entry, never channel by channel
    coupled: bool = False

    @classmethod
    def of(cls, source: ModelSource, names: Iterable[str], shapes) -> ParamLayout:
        names = tuple(names)
        specs = [source.param(n) for n in names]
        return cls(names, tuple(tuple(int(d) for d in s) for s in shapes),
                   tuple(p.transform for p in specs), tuple(p.channels for p in specs),
                   bool(getattr(source, "coupled", False)))

    @functools.cached_property
    def sizes(self) -> tuple[int, ...]:
        return tuple(int(np.prod(s)) if s else 1 for s in self.shapes)

    @functools.cached_property
    def slices(self) -> tuple[slice, ...]:
        """Where each parameter sits in the flat vector (the one offset loop)."""
        out, k = [], 0
        for size in self.sizes:
            out.append(slice(k, k + size))
            k += size
        return tuple(out)

    @property
    def size(self) -> int:
        return sum(self.sizes)

    def split(self, x) -> dict:
        """Flat ``(..., size)`` -> ``{name: (..., *shape)}``."""
        lead = x.shape[:-1]
        return {n: x[..., sl].reshape((*lead, *s))
                for n, s, sl in zip(self.names, self.shapes, self.slices, strict=True)}

    def join(self, parts: Mapping, xp=jnp, dtype=None):
        """``{name: (..., *shape)}`` -> flat ``(..., size)`` (inverse of :meth:`split`; no
        free parameter: ``zeros(0, dtype)``)."""
        if not self.names:
            return xp.zeros(0, dtype)
        first = parts[self.names[0]]
        lead = np.shape(first)[:np.ndim(first) - len(self.shapes[0])]
        return xp.concatenate([xp.reshape(parts[n], (*lead, -1)) for n in self.names], axis=-1)

    def forward(self, parts: Mapping) -> dict:
        """``{name: unconstrained}`` -> ``{name: physical}`` (the transforms)."""
        return {n: tr.forward(parts[n]) for n, tr in zip(self.names, self.transforms,
                                                         strict=True)}

    def inverse(self, values: Mapping, lead: tuple[int, ...] = ()) -> np.ndarray:
        """Physical ``{name: (*lead, *shape)}`` -> the unconstrained flat ``(*lead, size)``
        (NumPy; start values)."""
        if not self.names:
            return np.zeros((*lead, 0))
        return np.concatenate([np.reshape(tr.inverse(values[n]), (*lead, -1))
                               for n, tr in zip(self.names, self.transforms, strict=True)],
                              axis=-1)

    def structured(self, n_channels: int) -> tuple[bool, ...]:
        """Per parameter: a channel parameter the structured Jacobian takes with one tangent
        for all channels (declared a channel parameter, shape ``(C,)``, of a model that does
        not couple its channels)."""
        return tuple(c and tuple(s) == (n_channels,) and not self.coupled
                     for c, s in zip(self.channels, self.shapes, strict=True))

    def channel_index(self, n_channels: int) -> np.ndarray:
        """Per flat entry: its channel for a channel parameter of ``n_channels`` entries, else
        -1 (a shared entry)."""
        idx = np.full(self.size, -1, int)
        if self.coupled:  # one design dimension per parameter, no per-channel pick
            return idx
        for c, size, sl in zip(self.channels, self.sizes, self.slices, strict=True):
            if c and size == n_channels:
                idx[sl] = np.arange(size)
        return idx

    def at_bound(self, params: Mapping) -> np.ndarray:
        """Per flat entry: whether the fitted value (``params``: physical, by name) sits at an
        end of its interval (:func:`at_bound`)."""
        return np.asarray(self.join({n: at_bound(tr, np.asarray(params[n])) for n, tr in
                                     zip(self.names, self.transforms, strict=True)}, xp=np),
                          bool)

    def mask(self, names) -> np.ndarray:
        """Per flat entry: whether it belongs to one of ``names``."""
        m = np.zeros(self.size, bool)
        for n, sl in zip(self.names, self.slices, strict=True):
            if n in names:
                m[sl] = True
        return m


# ----------------------------------------------------------------------------- the problem


@dataclasses.dataclass(frozen=True, eq=False)
class FitProblem:
    """A fit, static part: the model source, the flat layout of its free parameters, the
    values of the others (``fixed``, physical; fit_batch passes them per problem instead and
    keeps this empty), the metric and ``cos_weight``. Pure functions of the flat vector, for
    the solvers (jit/vmap-able)."""

    source: ModelSource
    layout: ParamLayout
    fixed: dict
    metric: str
    cos_weight: bool

    @classmethod
    def of(cls, model, free=None, shapes=None, fixed=None, metric: str = "log",
           cos_weight: bool = False, n_channels: int | None = None) -> FitProblem:
        """A problem for ``model`` (registry name, Entry, built model or source): ``free``
        (default: every parameter not in ``fixed``) with ``shapes`` (default: template shapes;
        a registry channel parameter ``(n_channels,)``, or its default's shape)."""
        source = model_source(model)
        fixed = dict(fixed or {})
        free = tuple(n for n in source.names if n not in fixed) if free is None else tuple(free)
        if shapes is None:
            def shape(p):
                if p.shape is not None:
                    return p.shape
                if p.channels and n_channels is not None:
                    return (n_channels,)
                return np.shape(p.default)
            shapes = tuple(shape(source.param(n)) for n in free)
        check_choice("metric", metric, METRICS)
        return cls(source, ParamLayout.of(source, free, shapes), fixed, metric, cos_weight)

    # the layout's parts, by their old names
    @property
    def free(self) -> tuple[str, ...]:
        return self.layout.names

    @property
    def shapes(self) -> tuple[tuple[int, ...], ...]:
        return self.layout.shapes

    @property
    def transforms(self) -> tuple[Transform, ...]:
        return self.layout.transforms

    @property
    def key(self):
        """Hashable: equal for problems whose solvers compile to the same function."""
        return (self.source.key, self.layout, self.metric, self.cos_weight)

    def fixed_signature(self):
        """Hashable: the names, shapes and dtypes of the fixed values (what a compiled program
        of this problem depends on besides :attr:`key`; their values are its arguments)."""
        return tuple(sorted((k, tuple(np.shape(v)), str(jnp.asarray(v).dtype))
                            for k, v in self.fixed.items()))

    def with_fixed(self, fixed) -> FitProblem:
        return dataclasses.replace(self, fixed=fixed)

    def build(self, params):
        """The model at ``params`` (physical; missing names take their defaults)."""
        return self.source.build(params)

    def split(self, x):
        """Flat vector (free parameters in order, each raveled) -> {name: array of its shape}."""
        return self.layout.split(x)

    def physical(self, parts):
        """{free name: unconstrained value} -> all physical parameters (fixed ones included)."""
        return {**self.fixed, **self.layout.forward(parts)}

    def unflatten(self, u):
        """Unconstrained flat ``u`` -> all physical parameters (the fixed ones included)."""
        return self.physical(self.split(u))

    def residuals_at(self, params, arrays):
        """Residual vector of the model built from ``params`` (all parameters, physical)."""
        return self.residuals_prepared(params, self.prepare(arrays, jnp)).reshape(-1)

    def residuals(self, u, arrays):
        """Residuals as a function of the unconstrained flat ``u`` (what the solvers see)."""
        return self.residuals_at(self.unflatten(u), arrays)

    def residuals_phys(self, x, arrays):
        """Residuals as a function of the flat free *physical* parameters (for standard
        errors: the Jacobian in the parameters the user reads)."""
        return self.residuals_at({**self.fixed, **self.split(x)}, arrays)

    def prepare(self, arrays, xp=np):
        """``arrays`` (wi, wo, f, w, sigma, floor; leading batch axes allowed; ``w`` None: all
        1) -> the prepared tuple ``(wi, wo, mul, gf, scale)`` of :meth:`residuals_prepared`.
        ``xp``: numpy or jax.numpy (fit_batch prepares on the device)."""
        wi, wo, f, w, sigma, floor = (None if a is None else xp.asarray(a) for a in arrays)
        mul, gf, scale = metric_parts(self.metric, f, wi[..., 2:3], sigma, w, floor,
                                      self.cos_weight, xp)
        return wi, wo, mul, gf, scale

    def residuals_prepared(self, params, prep):
        """Residuals ``(M, C)`` (not flattened) of the model built from ``params`` (all,
        physical) on prepared data (:meth:`prepare`)."""
        wi, wo = prep[:2]
        return self.residuals_of_values(self.build(params).eval(wi, wo), prep)

    def residuals_of_values(self, m, prep):
        """Residuals ``(M, C)`` of model values ``m`` ((M, C), or (M,) for a model without
        channels) on prepared data (:meth:`prepare`): the metric's half of
        :meth:`residuals_prepared` (the grid guess reuses model values computed once for a
        whole batch of one geometry, :func:`brdf_fit.fitting.guess.shared_losses`)."""
        mul, gf, scale = prep[2:]
        if m.ndim == 1:
            m = m[:, None]
        r = METRIC_H[self.metric](m * mul) - gf
        r = r if scale is None else r * scale
        return robust_residual(self.metric, r) if self.metric in ROBUST else r
