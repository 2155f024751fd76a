"""The BRDF interface and its conventions.

Conventions (DESIGN.md section 2; each one is tested in ``tests/test_conventions.py``)
-------------------------------------------------------------------------------------

Frame
    Local shading frame: ``z`` is the normal ``n``, ``x`` the tangent ``t`` (the anisotropy axis,
    ``alpha_x`` is the width along it), ``y`` the bitangent ``b = n x t``.
Directions
    ``wi`` (toward the light) and ``wo`` (toward the viewer) are unit vectors pointing **away**
    from the surface, arrays of shape ``(..., 3)``. Batch dimensions broadcast.
``eval(wi, wo)``
    The BRDF ``f_r`` in 1/sr, **without** the cosine factor. It is 0 when either direction is at
    or below the horizon (``z <= 0``). Delta lobes (the mirror) cannot be evaluated and return 0.
``pdf(wi, wo)``
    Solid-angle density with which :meth:`sample` draws ``wi`` given ``wo``; 0 where ``sample``
    never lands (below the horizon, or ``wo`` below the horizon). Its integral over the upper
    hemisphere is ``1 - P(sampling fails)``.
``sample(wo, uc, u)``
    Takes uniforms, not PRNG keys: ``uc`` of shape ``(...)`` picks a lobe (single-lobe models may
    use it for their own discrete choices), ``u`` of shape ``(..., 2)`` picks the direction.
    Returns a :class:`BRDFSample` with ``wi``, ``pdf`` and ``weight = f cos(theta_i) / pdf``.
    A failed sample has ``pdf = 0`` and ``weight = 0``, never NaN. Delta lobes return ``pdf = 1``
    (a discrete probability, flagged by ``is_delta``) and ``weight`` = the reflectance.
Roughness
    Models store ``alpha`` (the width in D). The "perceptual roughness" ``r`` with ``alpha = r^2``
    is the named conversion :func:`brdf_fit.roughness_to_alpha`, never applied silently.
Channels
    Colour parameters (albedo, F0, eta, k) may carry a trailing channel axis (RGB or wavelengths);
    geometric parameters (alpha, exponents) are scalars. ``eval`` and ``weight`` then have shape
    ``batch + (C,)``; ``pdf`` has shape ``batch``. Batches of *models* use ``jax.vmap``.
dtype
    float32 by default, float64 when ``jax_enable_x64`` is on; kernels hard-code no dtype.
Units
    Radians inside the library; degrees only at file and CLI boundaries, in names ending ``_deg``.
"""

from __future__ import annotations

import abc
import functools
from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp


class BRDFSample(eqx.Module):
    """Result of :meth:`AbstractBRDF.sample`: direction, its pdf, and ``f cos / pdf``."""

    wi: jax.Array
    pdf: jax.Array
    weight: jax.Array


def n_channels(tree) -> int | None:
    """Length of the trailing channel axis carried by the parameters of ``tree`` (None if all
    parameters are scalars). Static under ``jit`` and ``vmap``."""
    sizes = {int(jnp.shape(x)[-1]) for x in jax.tree_util.tree_leaves(tree) if jnp.ndim(x) > 0}
    if not sizes:
        return None
    sizes.discard(1)
    if len(sizes) > 1:
        raise ValueError(f"parameters carry inconsistent channel counts {sorted(sizes)}")
    return sizes.pop() if sizes else 1


def expand_channels(x, channels: int | None):
    """Append a channel axis of size 1 to a per-direction quantity when the model has channels."""
    return x if channels is None else x[..., None]


class QuadratureLobe(NamedTuple):
    """What a lobe declares about its shape (:meth:`AbstractBRDF.quadrature_lobe`), so that
    quadrature (:func:`brdf_fit.verify.albedo.lobe_rule`) and the chi-square grid can follow it.

    ``kind``: ``"mirror"``: a power-cosine lobe about the mirror direction, ``value`` its exponent
    (:func:`brdf_fit.core.mirror_rule.mirror_lobe_rule`); ``"half"``: a half-vector lobe of Beckmann
    width ``value``, or ``(width_x, width_y)`` when anisotropic
    (:func:`brdf_fit.core.quadrature.halfvector_rule`); ``"mu"``: a lobe that depends on ``wi``
    only through ``mu_i = cos(theta_i)``, ``value = (mu, w)`` its own rule in ``mu`` (nodes in
    (0, 1] and weights, ``Int_0^1 g(mu) dmu ~ sum w g(mu)``), which quadrature takes times a
    small trapezoid rule in the azimuth (:func:`brdf_fit.core.quadrature.azimuthal_rule`);
    ``"none"``: nothing declared."""

    kind: str
    value: Any = None


#: The default of :meth:`AbstractBRDF.quadrature_lobe`: no lobe shape declared.
NO_QUADRATURE_LOBE = QuadratureLobe("none")


#: the public methods that run as one compiled program when called outside a JAX trace
COMPILED_METHODS = ("eval", "pdf", "sample")


def _traced(tree) -> bool:
    """Whether any leaf of ``tree`` is a tracer (the call is inside ``jit``, ``grad``, ``vmap``
    ...: the caller's trace compiles it whole already)."""
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(tree))


def _as_arrays(tree):
    """``tree`` with its Python float and complex leaves as weak-typed JAX arrays (their dtype
    and promotion unchanged). ``equinox.filter_jit`` holds every non-array leaf static, so a
    model built with ``alpha=0.3`` would compile once per value of alpha: a sweep over alpha
    in a Python loop would compile every step."""
    def convert(x):
        return jnp.asarray(x) if isinstance(x, (float, complex)) else x

    return jax.tree_util.tree_map(convert, tree)


def compiled_outside_traces(method):
    """``method`` (a model's ``eval``, ``pdf`` or ``sample``) as one compiled program when it is
    called eagerly, and as itself inside a trace. Called eagerly, JAX dispatches a model's
    operations one by one, each compiled on first use and each a pass over memory (issue 44;
    a first ggx-conductor evaluation of 1,000 pairs in a fresh process took 1.45 s that way and
    0.16 s compiled whole, a second 7.6 ms and 0.6 ms, measured 2026-12-06 on 2 AMD EPYC cores;
    ``tests/models/test_compiled_methods.py`` counts the programs). One program
    per model structure (the static fields and the tree of parameters) and argument shapes
    (``equinox.filter_jit``'s cache); the parameters' values are arguments, not constants.
    ``method.raw`` is the method itself."""
    jitted = eqx.filter_jit(method)

    @functools.wraps(method)
    def call(self, *args, **kwargs):
        if _traced((self, args, kwargs)):
            return method(self, *args, **kwargs)
        return jitted(_as_arrays(self), *_as_arrays(args), **_as_arrays(kwargs))

    call.raw = method
    return call


class AbstractBRDF(eqx.Module):
    """A BRDF: evaluate, sample and report the sampling density (see the module docstring for the
    conventions, which every subclass follows). Subclasses are final; compose, don't inherit.

    Besides ``eval``, ``pdf`` and ``sample`` a model may override the declared hooks below (each
    has a default): :meth:`quadrature_lobe`, :meth:`terms`, :meth:`pdf_terms`,
    :meth:`is_anisotropic`, :meth:`delta_albedo`, :meth:`selection_hint`, :meth:`channels`.

    A subclass's ``eval``, ``pdf`` and ``sample`` called outside a JAX trace each run as one
    compiled program (:func:`compiled_outside_traces`, applied to every subclass); inside
    ``jit``, ``grad`` or ``vmap`` they are traced as written.
    """

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        for name in COMPILED_METHODS:
            method = cls.__dict__.get(name)
            if callable(method) and not hasattr(method, "raw"):
                setattr(cls, name, compiled_outside_traces(method))

    is_delta: ClassVar[bool] = False
    #: whether ``f`` depends on the azimuth of the view (the checks then look at three azimuths);
    #: read through :meth:`is_anisotropic`
    anisotropic: ClassVar[bool] = False

    @abc.abstractmethod
    def eval(self, wi, wo):
        """``f_r(wi, wo)`` in 1/sr, without the cosine; shape ``batch`` or ``batch + (C,)``."""

    @abc.abstractmethod
    def pdf(self, wi, wo):
        """Solid-angle density of :meth:`sample` drawing ``wi`` given ``wo``; shape ``batch``."""

    @abc.abstractmethod
    def sample(self, wo, uc, u) -> BRDFSample:
        """Draw ``wi`` given ``wo`` from uniforms ``uc`` (...) and ``u`` (..., 2)."""

    def channels(self) -> int | None:
        """Channel count of the outputs (None: scalar outputs)."""
        return n_channels(self)

    def selection_hint(self):
        """A non-negative scalar proportional to how much this lobe reflects; mixtures pick lobes
        with probability proportional to it. Default 1."""
        return jnp.asarray(1.0)

    def eval_cos(self, wi, wo):
        """``f_r(wi, wo) max(0, cos theta_i)``, the integrand of the directional albedo."""
        c = jnp.maximum(wi[..., 2], 0.0)
        return self.eval(wi, wo) * expand_channels(c, self.channels())

    # ------------------------------------------------------------------ declared hooks

    def quadrature_lobe(self) -> QuadratureLobe:
        """The lobe shape quadrature should follow (:class:`QuadratureLobe`). Default: none
        declared (:data:`NO_QUADRATURE_LOBE`); the verification then picks a rule by type."""
        return NO_QUADRATURE_LOBE

    def terms(self) -> tuple[tuple[Any, AbstractBRDF], ...]:
        """``((scale_j, lobe_j), ...)`` with ``f = sum_j scale_j f_j``, one level down (a
        :class:`~brdf_fit.models.Mixture` or :class:`~brdf_fit.models.Scaled` unfolds; a single
        lobe is ``((1.0, self),)``, the default). Quadrature integrates lobe by lobe with it."""
        return ((1.0, self),)

    def pdf_terms(self) -> tuple[tuple[Any, AbstractBRDF], ...]:
        """``((p_j, lobe_j), ...)`` with ``pdf = sum_j p_j pdf_j``, one level down (default
        ``((1.0, self),)``)."""
        return ((1.0, self),)

    def is_compound(self) -> bool:
        """Whether :meth:`terms` unfolds this model into other lobes."""
        return False

    def is_anisotropic(self) -> bool:
        """Whether ``f`` depends on the azimuth of the view (default: the class's
        ``anisotropic``)."""
        return self.anisotropic

    def prepared(self) -> AbstractBRDF:
        """The model as a renderer holds it: what depends on the parameters alone (a table a
        plugin builds when its parameters change) computed once, so that ``eval`` costs what a
        renderer's per-pair evaluation costs. The values are the same. Default: ``self``
        (nothing to precompute); compound models prepare their lobes. Cost measurements
        (:func:`brdf_fit.selection.measure_cost`, ``benchmarks/bench_catalogue_cost.py``) time
        the prepared model."""
        return self

    def delta_albedo(self, wo):
        """Closed-form directional albedo of a delta lobe (``is_delta``), which quadrature cannot
        integrate. Default: raises ``TypeError``."""
        raise TypeError(f"delta lobe {type(self).__name__} has no closed-form albedo(wo)")


def astype(model, dtype):
    """Copy of ``model`` with every floating-point parameter cast to ``dtype``."""

    def cast(x):
        if eqx.is_array(x) and jnp.issubdtype(x.dtype, jnp.floating):
            return x.astype(dtype)
        if isinstance(x, float):
            return jnp.asarray(x, dtype=dtype)
        return x

    return jax.tree_util.tree_map(cast, model)


def evaluate(model, wi, wo):
    """``model.eval(wi, wo)``, which outside a trace is one compiled program
    (:func:`compiled_outside_traces`; a name kept for the callers that wrote it when ``eval``
    itself dispatched op by op)."""
    return model.eval(wi, wo)
