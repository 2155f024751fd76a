"""The fitting problem: which parameters a fit varies, how they map to the solver's flat
unconstrained vector, and the residual of the model they build. :func:`brdf_fit.fitting.single.fit`,
:func:`brdf_fit.fitting.batch.fit_batch` and :mod:`brdf_fit.fitting.guess` all work on a
:class:`FitProblem`.

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

**The flat layout** (:class:`ParamLayout`): the free parameters, in order, each raveled into the
flat vector ``u`` at its :attr:`~ParamLayout.slices`; the physical value is ``transform.forward``
of its slice (:class:`Transform`). Every split, join, inverse, channel index and mask of the
flat vector goes through this one layout.

**Residual metrics** (per sample and channel; ``f`` measured, ``m`` model, ``c = cos(theta_i)``):

``log``       ``ln(1 + m c) - ln(1 + f c)``  (J. Low, J. Kronander, A. Ynnerman, J. Unger, "BRDF
              models for accurate and efficient rendering of glossy surfaces", ACM TOG 31(1),
              2012, section 5: compresses the specular peak so the lobe shape counts)
``cuberoot``  ``cbrt(m) - cbrt(f)``  (a cube-root compression of the dynamic range)
``relative``  ``(m - f)/max(f, floor)``
``absolute``  ``m - f``

With per-sample ``sigma`` the residual is divided by the metric's first-order standard deviation
``g'(f) sigma`` (the delta method); otherwise it is multiplied by ``sqrt(weight)``.
``cos_weight`` multiplies by ``cos(theta_i)``.

**Robust metrics** (for data with outliers): the (weighted) ``log`` residual ``r``, then a
robust loss ``rho`` of scale ``s`` = :data:`ROBUST_SCALE` (in log units), written as the
residual ``sign(r) s sqrt(2 rho(r / s))`` so that least squares minimises ``sum s^2 rho(r/s)``
(the square-rooted robust residual of B. Triggs, P. McLauchlan, R. Hartley, A. Fitzgibbon,
"Bundle adjustment - a modern synthesis", Vision Algorithms 1999, LNCS 1883, section 4.3):

``huber``     ``rho(x) = x^2/2`` for ``|x| <= 1``, ``|x| - 1/2`` beyond (P. J. Huber, "Robust
              estimation of a location parameter", Ann. Math. Statist. 35(1), 1964): quadratic
              for the noise, linear for outliers
``cauchy``    ``rho(x) = log(1 + x^2)/2`` (the Cauchy or Lorentzian loss; Triggs et al., and
              M. J. Black & P. Anandan, CVIU 63(1), 1996): an outlier's pull vanishes as it grows

Their loss, rms and standard errors are those of the transformed residuals (the standard errors
the Gauss-Newton approximation of the robust loss, not a robust covariance). Not with
``sigma`` (the scale is in log units, a sigma-weighted residual is in standard deviations).
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
from brdf_fit.core.validate import ParameterError

__all__ = [
    "FitProblem", "ParamLayout", "ParamSpec", "ModelSource", "RegistrySource", "TemplateSource",
    "model_source", "resolve_free", "check_choice", "Transform", "FitError", "at_bound",
    "metric_parts", "robust_residual", "ROBUST", "ROBUST_SCALE",
    "METRICS", "METRIC_H", "RELATIVE_FLOOR", "DATA_SCALE_FLOOR", "EDGE", "AT_BOUND_REL",
    "RANK_RCOND", "DEAD_COLUMN_REL", "NULL_SHARE", "STDERR_NOTES", "stderr_codes", "stderr_notes",
    "UNDETERMINED_REL_STDERR", "UNDETERMINED_RULE", "undetermined", "entry_labels",
    "parameter_entries",
]

METRICS = ("log", "cuberoot", "relative", "absolute", "huber", "cauchy")
#: robust metrics: name -> the metric whose residual the robust loss is applied to
ROBUST = {"huber": "log", "cauchy": "log"}
#: Scale ``s`` of the robust metrics in units of the (weighted) log residual
#: ``ln(1 + m c) - ln(1 + f c)``: 0.05, a 5% deviation of ``1 + f c``, is 5x the largest log
#: residual of 1% noise (the benchmarks' and the synthetic recipes' level) and far below a
#: corrupt sample (a value 1e6 where the model gives ~1: ~14).
ROBUST_SCALE = 0.05
#: Floor of the denominator of the relative metric, as a fraction of the data's largest value:
#: keeps near-zero measurements (dark tails) from dominating.
RELATIVE_FLOOR = 1e-3
#: Smallest data scale the relative floor is taken of (all-zero data would give a zero floor).
DATA_SCALE_FLOOR = 1e-300
#: Logistic/softplus inverses clip the normalised value to [EDGE, 1 - EDGE]: a start exactly on a
#: bound would map to +-inf.
EDGE = 1e-9
#: Smallest ``g'(f) sigma`` a sigma-weighted residual is divided by (a sample with sigma = 0 and
#: positive weight would otherwise divide by zero); far below any measured standard deviation.
SIGMA_FLOOR = 1e-300
#: A fitted value this close to an interval end (relative to max(1, |bound|), or to the
#: interval's width where that is smaller) is reported as at its bound: there the
#: unconstrained solver has (almost) no gradient left, so the value is a limit, not an optimum
#: of the model, and its standard error describes nothing (e.g. an f0 channel pushed to 1).
#: 1e-4: a logistic parameter creeps towards its end ever more slowly (its slope t (1 - t)
#: vanishes); optimistix's LM stopped an f0 that wanted to exceed 1 at 1 - 1.4e-6 after 256
#: steps, batch-lm at 1 - 1e-16 (measured). Near an end the logistic's slope is about the
#: distance to it, whatever the width, so a wide interval does not widen the tolerance: relative
#: to the width alone, a Phong exponent of 6.3 in [0, 1e6] (the demo's fit) counted as at its
#: bound (tolerance 100) and, since issue 16, lost its standard error.
AT_BOUND_REL = 1e-4


class FitError(ValueError):
    """A fit request that cannot be honoured (unknown parameter, bad option)."""


# ----------------------------------------------------------------------------- transforms


@dataclasses.dataclass(frozen=True)
class Transform:
    """Map between a parameter's interval and the real line: ``[lo, hi]`` a scaled logistic,
    ``[lo, inf)`` ``lo + softplus``, ``(-inf, hi]`` ``hi - softplus(-u)``, unbounded the
    identity. Open and closed ends map alike (the solver never reaches an end)."""

    lo: float | None
    hi: float | None

    @classmethod
    def of(cls, interval) -> Transform:
        """The transform of anything with ``lo`` and ``hi`` (a registry ``Param``, an
        :class:`~brdf_fit.core.params.Interval`; None: unbounded)."""
        if interval is None:
            return cls(None, None)
        lo, hi = interval.lo, interval.hi
        return cls(None if lo is None else float(lo), None if hi is None else float(hi))

    def forward(self, u):
        if self.lo is not None and self.hi is not None:
            return self.lo + (self.hi - self.lo) * jax.nn.sigmoid(u)
        if self.lo is not None:
            return self.lo + jax.nn.softplus(u)
        if self.hi is not None:
            return self.hi - jax.nn.softplus(-u)
        return u

    def inverse(self, x):
        """NumPy inverse (start values); ``log(-expm1(-y)) + y`` is the stable inverse
        softplus."""
        x = np.asarray(x, float)
        if self.lo is not None and self.hi is not None:
            t = np.clip((x - self.lo) / (self.hi - self.lo), EDGE, 1 - EDGE)
            return np.log(t) - np.log1p(-t)
        if self.lo is not None:
            y = np.maximum(x - self.lo, EDGE)
            return y + np.log(-np.expm1(-y))
        if self.hi is not None:
            y = np.maximum(self.hi - x, EDGE)
            return -(y + np.log(-np.expm1(-y)))
        return x


def at_bound(param, value) -> np.ndarray:
    """Boolean array (shape of ``value``): which entries of a fitted value sit at an end of the
    interval of ``param`` (anything with ``lo`` and ``hi``: a :class:`Transform`, a registry
    ``Param``; see :data:`AT_BOUND_REL`)."""
    x = np.asarray(value, float)
    out = np.zeros(x.shape, bool)
    lo, hi = param.lo, param.hi
    scale = (hi - lo) if (lo is not None and hi is not None) else None
    for b in (lo, hi):
        if b is not None:
            near = max(1.0, abs(b))
            tol = AT_BOUND_REL * (min(scale, near) if scale is not None else near)
            out |= np.abs(x - b) <= tol
    return out


# ----------------------------------------------------------------------------- identifiability


#: Relative threshold of the numerical rank of the normal equations ``A = J^T J`` in the free
#: physical parameters, taken on the correlation-scaled ``R = D^-1/2 A D^-1/2`` (``D = diag(A)``,
#: so the test does not depend on the parameters' units; R's eigenvalues sum to p): an
#: eigenvalue below ``RANK_RCOND * max`` (a singular value of the column-scaled ``J`` below 1e-5
#: of the largest) is a combination of parameters the data determine 1e5 times less well than
#: the best-determined one, i.e. not at all. The rounding of ``J^T J`` in float64 is ~1e-13
#: relative (m ~ 1e4 samples), far below; two parameters that enter only as a product give
#: ~1e-16 (measured), well-posed fits of the test suite >= 1e-5 (measured). For a lower
#: precision the threshold is raised to 1e3 eps of that dtype (1.2e-4 in float32).
RANK_RCOND = 1e-10
#: A parameter whose Jacobian column has a norm below this fraction of the largest column's is
#: not identifiable outright: ``numpy.linalg.pinv`` (rcond 1e-15 on ``A``, i.e. ~3e-8 on the
#: columns of ``J``) drops such a direction and reports a confidently small, meaningless error
#: (gold's red channel at F ~ 1 in the demo: 1e-10).
DEAD_COLUMN_REL = 3e-8
#: A parameter takes part in a rank-deficient direction ``v`` (unit eigenvector of R) when
#: ``|v_i| > NULL_SHARE``: its variance along ``v``, ``v_i^2 / lambda``, is unbounded as lambda
#: -> 0; 0.01 (1e-4 of the direction's squared length) ignores the rounding-level components
#: an eigenvector carries on the well-determined parameters.
NULL_SHARE = 0.01
#: Why a standard error is undefined (NaN), by code (:func:`stderr_codes`; 0: defined).
STDERR_NOTES = {1: "at bound", 2: "not identifiable", 3: "non-finite normal equations"}


def stderr_codes(A, finite=None, xp=np):
    """Per flat free parameter (``A``: ``J^T J`` (p, p) in the physical parameters): 0 when its
    standard error is defined, 2 when it is not identifiable (its Jacobian column vanishes,
    :data:`DEAD_COLUMN_REL`, or it takes part in a direction of numerical rank deficiency,
    :data:`RANK_RCOND`, :data:`NULL_SHARE`), 3 for every parameter when the normal equations
    are not finite (``finite``: that test, default computed from ``A``). NumPy or JAX (jit,
    vmap: ``xp=jnp``); at-bound flags (code 1) are added by the caller (:func:`at_bound`)."""
    p = A.shape[-1]
    if finite is None:
        finite = xp.all(xp.isfinite(A))
    A = xp.where(finite, A, xp.eye(p, dtype=A.dtype))  # no eigensolver on inf/NaN
    d = xp.sqrt(xp.maximum(xp.diagonal(A), 0.0))
    dead = d <= DEAD_COLUMN_REL * xp.max(d)
    ds = xp.where(dead, 1.0, d)
    live = ~dead
    R = xp.where(live[:, None] & live[None, :], A / (ds[:, None] * ds[None, :]), 0.0)
    w, V = xp.linalg.eigh(R)
    rcond = max(RANK_RCOND, 1e3 * float(np.finfo(np.dtype(A.dtype)).eps))
    small = w <= rcond * xp.max(w)
    implicated = xp.any(small[None, :] & (xp.abs(V) > NULL_SHARE), axis=-1)
    code = xp.where(dead | implicated, 2, 0)
    return xp.where(finite, code, 3)


#: A fitted parameter is flagged *undetermined* by the data when its standard error exceeds
#: this fraction of its magnitude: its ~95% interval (+-1.96 sigma) then spans more than +-49%
#: of the value, so the data do not fix it to within a factor of about two. A statement about
#: the data, not the optimiser: such a value can land far from the truth while the fit is at
#: the noise (the demo's gold: F0 in red is ~0.99 whatever (eta, k) give it, and the fit returns
#: k[R] = 1.17 +- 0.71 and eta[R] = 0.0032 +- 0.0021 against a truth of 7.5 and 0.060,
#: relative errors 0.60 and 0.65, where every other parameter of that fit is below 0.03).
#: A parameter whose standard error is undefined because it is not identifiable (code 2 of
#: :func:`stderr_codes`) is undetermined too; one at an interval end is reported as at bound.
UNDETERMINED_REL_STDERR = 0.25
UNDETERMINED_RULE = (f"relative standard error > {UNDETERMINED_REL_STDERR:g}, or not "
                     "identifiable: the data do not determine the value")


def undetermined(value, stderr, note=None) -> np.ndarray:
    """Boolean mask (the shape of ``value``): the entries the data do not determine
    (:data:`UNDETERMINED_REL_STDERR`): a finite standard error above that fraction of ``|value|``,
    or an undefined one whose ``note`` (:func:`stderr_notes`) says "not identifiable"."""
    v = np.asarray(value, float)
    se = np.broadcast_to(np.asarray(stderr, float), v.shape)
    with np.errstate(invalid="ignore"):
        big = np.isfinite(se) & (se > UNDETERMINED_REL_STDERR * np.abs(v))
    if note is not None:
        n = np.broadcast_to(np.asarray(note, object), v.shape)
        big = big | (n == STDERR_NOTES[2])
    return big


def entry_labels(name: str, shape, channels=()) -> list[str]:
    """Labels of a parameter's entries, flattened: ``name`` for a scalar, ``name[R]`` per channel
    when the size matches ``channels``, else ``name[j]``."""
    size = int(np.prod(shape)) if len(shape) else 1
    if not len(shape) or size == 1:
        return [name]
    if len(channels) == size:
        return [f"{name}[{c}]" for c in channels]
    return [f"{name}[{j}]" for j in range(size)]


def parameter_entries(params: dict, stderr: dict, channels=()):
    """``(name, j, label, value, standard error)`` for every entry of every parameter in
    ``params`` (flattened; ``label`` as :func:`entry_labels`), the standard error from
    ``stderr`` (NaN where undefined) or None where the parameter has none (a fixed one): the
    rows of the command line's and the report pages' parameter tables."""
    for name, value in params.items():
        v = np.asarray(value, float).reshape(-1)
        se = stderr.get(name)
        se = None if se is None else np.asarray(se, float).reshape(-1)
        for j, label in enumerate(entry_labels(name, np.shape(value), channels)):
            yield name, j, label, float(v[j]), None if se is None else float(se[j])


def stderr_notes(codes, shape=None) -> np.ndarray:
    """Codes (:func:`stderr_codes`, at-bound 1) -> an array of reasons ("" where defined)."""
    c = np.asarray(codes)
    out = np.full(c.shape, "", dtype=object)
    for k, why in STDERR_NOTES.items():
        out[c == k] = why
    return out if shape is None else out.reshape(shape)


# ----------------------------------------------------------------------------- metrics


#: The metrics as ``g(m) = h(m * mul) - g(f)`` (see :func:`metric_parts`).
METRIC_H = {"log": jnp.log1p, "cuberoot": jnp.cbrt, "relative": lambda x: x,
            "absolute": lambda x: x, "huber": jnp.log1p, "cauchy": jnp.log1p}


def robust_residual(name, r, s=ROBUST_SCALE):
    """``sign(r) s sqrt(2 rho(r/s))`` for the robust metric ``name`` (module docstring):
    ``r`` itself for ``|r| <= s`` (huber) or to first order (cauchy); differentiable
    everywhere (the branches are guarded so no NaN reaches a derivative)."""
    x = r / s
    if name == "huber":
        big = jnp.abs(x) > 1.0
        a = jnp.where(big, jnp.abs(x), 1.0)
        return s * jnp.where(big, jnp.sign(x) * jnp.sqrt(2.0 * a - 1.0), x)
    if name == "cauchy":
        x2 = x * x
        small = x2 < 1e-8
        y = jnp.where(small, 1.0, x2)
        return s * x * jnp.where(small, 1.0 - 0.25 * x2, jnp.sqrt(jnp.log1p(y) / y))
    raise FitError(name)  # pragma: no cover - validated earlier


def metric_parts(name, f, c, sigma, w, floor, cos_weight, xp=np):
    """The residual metrics, data side: ``(mul, gf, scale)`` such that the residual of model
    values ``m`` is ``(h(m * mul) - gf) * scale`` with ``h`` = :data:`METRIC_H` [name] (log:
    ``h = log1p``, ``mul = cos``; cube root: ``h = cbrt``; relative: ``mul = 1/den``; absolute:
    identity), ``gf = h(f * mul)``, and ``scale`` the weight (``sqrt(w)``, or
    ``1/(g'(f) sigma)`` where ``w > 0``) times ``cos`` with ``cos_weight``; relative is
    evaluated as ``m/den - f/den``. fit() computes it inside its residual (differentiable with
    respect to the data); the batch solver once per call, so the data terms (for ``log``, half
    of the transcendental calls) are not recomputed at every iteration. ``f``, ``w`` (None:
    all 1), ``sigma`` (or None): (..., M, C); ``c``: (..., M, 1); ``floor``: (...,). ``mul``
    is (..., M, 1) except for ``relative`` (..., M, C); ``scale`` is None without weights,
    sigma and ``cos_weight``. ``xp``: numpy or jax.numpy."""
    if name in ROBUST:
        if sigma is not None:
            raise FitError(f"metric {name!r} is not for data with sigma (its scale "
                           f"{ROBUST_SCALE:g} is in log units); use 'log'")
        name = ROBUST[name]
    floor = xp.asarray(floor)[..., None, None]
    ones_c = xp.ones_like(c)
    if name == "log":
        mul = c
        gf = xp.log1p(f * c)
        dg = c / (1.0 + f * c)
    elif name == "cuberoot":
        mul, gf = ones_c, xp.cbrt(f)
        dg = 1.0 / (3.0 * xp.cbrt(xp.maximum(f, floor)) ** 2)
    elif name == "relative":
        den = xp.maximum(f, floor)
        mul = 1.0 / den
        gf, dg = f * mul, mul
    elif name == "absolute":
        mul, gf, dg = ones_c, f, xp.ones_like(f)
    else:  # pragma: no cover - validated earlier
        raise FitError(name)
    if sigma is not None:
        pos = xp.ones_like(f, dtype=bool) if w is None else w > 0
        scale = xp.where(pos, 1.0 / xp.maximum(dg * sigma, SIGMA_FLOOR), 0.0)
    elif w is not None:
        scale = xp.sqrt(w)
    else:  # no weights: no scale array (None), nothing to multiply at every iteration
        scale = c * xp.ones_like(f) if cos_weight else None
        return mul, gf, scale
    if cos_weight:
        scale = scale * c
    return mul, gf, scale


# ----------------------------------------------------------------------------- parameters


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
