"""Directional albedo of any model, lobe by lobe, each lobe with the quadrature rule suited to it.

``E(wo) = Int_H+ f(wi, wo) cos(theta_i) dwi``. By linearity a :class:`~brdf_fit.models.Mixture` or
:class:`~brdf_fit.models.Scaled` model is integrated lobe by lobe; each lobe gets the rule of
:mod:`brdf_fit.core.quadrature` that resolves it (the horizon-exact half-vector rule for
microfacet lobes, the mirror-lobe rule for power-cosine lobes, an exact small rule for Lambert).
Construction and convergence tables: docs/quadrature.md.
"""

from __future__ import annotations

import dataclasses
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit.core.microfacet import Beckmann, BlinnPhongNDF
from brdf_fit.core.mirror_rule import mirror_lobe_rule
from brdf_fit.core.quadrature import (
    HALFVECTOR_N_PHI,
    HALFVECTOR_N_THETA,
    Rule,
    azimuthal_rule,
    cosine_rule,
    gauss_legendre_hemisphere,
    halfvector_rule,
)
from brdf_fit.core.validate import ParameterError, PrecisionWarning
from brdf_fit.models import Lambert, MicrofacetBRDF
from brdf_fit.models._base import expand_channels

__all__ = [
    "GAUSSIAN_N_THETA",
    "GENERIC_N_MU",
    "GENERIC_N_PHI",
    "directional_albedo",
    "lobe_rule",
    "lobe_widths",
]

#: Gauss-Legendre x trapezoid rule for lobes of unknown shape in :func:`directional_albedo`
#: (8192 evaluations; accurate for smooth lobes only).
GENERIC_N_MU = 64
GENERIC_N_PHI = 128
#: Rule for Lambertian lobes (exact: the integrand rho/pi * mu is linear in mu).
_LAMBERT_RULE = (2, 2)
#: ``n_theta`` for lobes with Gaussian slope tails (Beckmann, Blinn-Phong): their steep radial
#: fall-off and the erf masking need more nodes along each ray than GGX (64 x 64 = 4096 reach
#: ~1e-7 at grazing views, where 48 x 64 leave up to 1e-5).
GAUSSIAN_N_THETA = 64


def _default_n_theta(lobe: MicrofacetBRDF) -> int:
    gaussian = isinstance(lobe.distribution, Beckmann | BlinnPhongNDF)
    return GAUSSIAN_N_THETA if gaussian else HALFVECTOR_N_THETA


def lobe_widths(lobe: MicrofacetBRDF):
    """``(alpha_x, alpha_y)`` of a :class:`~brdf_fit.models.MicrofacetBRDF` lobe as the lobe
    evaluates them (clamped below at ``ALPHA_MIN``): its distribution's
    :meth:`~brdf_fit.core.microfacet.AbstractDistribution.widths`.

    GGX and Beckmann: their ``alpha_x`` and ``alpha_y`` (``alpha_y = alpha_x`` when None);
    Blinn-Phong with exponent ``n``: the equivalent Beckmann width ``sqrt(2 / (n + 2))`` (Walter
    et al. 2007, section 5.2), e.g. 0.0141 for ``n = 1e4``. May return tracers.
    """
    return lobe.distribution.widths()


def lobe_rule(
    lobe,
    wo,
    n_theta: int | None = None,
    n_phi: int = HALFVECTOR_N_PHI,
    generic: tuple[int, int] = (GENERIC_N_MU, GENERIC_N_PHI),
    dtype=None,
) -> Rule:
    """The rule :func:`directional_albedo` integrates a single (non-composite, non-delta) lobe
    with: the rule a lobe asks for through its ``quadrature_lobe()`` method (``("mirror", n)``:
    :func:`mirror_lobe_rule` for power-cosine lobes about the mirror direction, the Phong family;
    ``("half", width)``: :func:`halfvector_rule` at that width, e.g. Blinn-Phong's equivalent
    Beckmann width ``sqrt(2/(n+2))``; ``("half", (width_x, width_y))`` for anisotropic
    lobes; ``("mu", (mu, w))``: the lobe's own rule in ``mu`` times :func:`azimuthal_rule`, for
    lobes that depend on ``wi`` through ``mu_i`` only), :func:`halfvector_rule` at the lobe's
    widths for a microfacet lobe, a small :func:`cosine_rule` (exact) for Lambert, the
    ``generic`` Gauss-Legendre x trapezoid product rule otherwise. Batched ``wo`` gives a
    batched rule for microfacet lobes only.
    ``n_theta=None``: 48 (:data:`HALFVECTOR_N_THETA`), 64 (:data:`GAUSSIAN_N_THETA`) for Beckmann
    and Blinn-Phong lobes."""
    kind, value = lobe.quadrature_lobe()
    if kind == "mirror":
        return mirror_lobe_rule(wo, value, dtype=dtype)
    if kind == "half":
        n_theta = GAUSSIAN_N_THETA if n_theta is None else n_theta
        ax, ay = value if isinstance(value, (tuple, list)) else (value, None)
        return halfvector_rule(wo, ax, ay, n_theta=n_theta, n_phi=n_phi, dtype=dtype)
    if kind == "mu":
        return azimuthal_rule(*value, dtype=dtype)
    if kind != "none":
        raise ValueError(f"{type(lobe).__name__}.quadrature_lobe() returned unknown kind {kind!r}")
    if isinstance(lobe, MicrofacetBRDF):
        n_theta = _default_n_theta(lobe) if n_theta is None else n_theta
        return halfvector_rule(wo, *lobe_widths(lobe), n_theta=n_theta, n_phi=n_phi, dtype=dtype)
    if isinstance(lobe, Lambert):
        return cosine_rule(*_LAMBERT_RULE, dtype=dtype)
    return gauss_legendre_hemisphere(*generic, dtype=dtype)


@eqx.filter_jit
def _rule_sum(lobe, directions, weights, wo):
    """``sum_k w_k f(wi_k, wo) cos(theta_i)`` over the last node axis (batched over ``wo``)."""
    vals = lobe.eval_cos(directions, wo[..., None, :])  # (..., N) or (..., N, C)
    with jax.numpy_dtype_promotion("standard"):
        dt = jnp.promote_types(weights.dtype, vals.dtype)
    w = weights.astype(dt)
    vals = vals.astype(dt)
    # values carry a channel axis when they have more axes than the broadcast of the nodes and
    # the views (comparing with the rule's own axes mistook a batch of views integrated by an
    # unbatched rule, values (n_wo, N), for channels)
    batch = jnp.broadcast_shapes(directions.shape[:-1], wo.shape[:-1] + (1,))
    if vals.ndim > len(batch):
        return jnp.sum(w[..., None] * vals, axis=-2)
    return jnp.sum(w * vals, axis=-1)


def _check_parameter_shapes(model, path: str = "") -> None:
    """Refuse a batch axis on a model parameter: the rules are built for one lobe (one set of
    widths), and a geometric parameter of shape ``(N, 1)`` broadcast against ``wo`` of shape
    ``(N, N, 3)`` gave ``(N, N, 1)`` values up to 18 for an albedo <= 1 (issue 16). A
    floating-point field may be a scalar, or a 1-D vector where its field declares channels
    (:func:`brdf_fit.core.params.bounded` with ``channels=True``); anything else raises
    :class:`~brdf_fit.core.validate.ParameterError` naming the parameter."""
    for f in dataclasses.fields(model):
        if f.metadata.get("static", False):
            continue
        v = getattr(model, f.name, None)
        name = f"{path}.{f.name}" if path else f.name
        if isinstance(v, eqx.Module):
            _check_parameter_shapes(v, name)
            continue
        if isinstance(v, list | tuple):
            for i, x in enumerate(v):
                if isinstance(x, eqx.Module):
                    _check_parameter_shapes(x, f"{name}.{i}")
            continue
        if not isinstance(v, jax.Array | np.ndarray) or not jnp.issubdtype(v.dtype, jnp.floating):
            continue
        channels = bool(f.metadata.get("channels", False))
        if v.ndim == 0 or (channels and v.ndim == 1):
            continue
        allowed = "a scalar or a 1-D channel vector" if channels else "a scalar"
        raise ParameterError(
            f"directional_albedo: {type(model).__name__}.{f.name} ({name}) has shape "
            f"{tuple(v.shape)}, but must be {allowed}: the quadrature rule is built for one "
            f"lobe. For a batch of models use jax.vmap over models, e.g. "
            f"jax.vmap(lambda a: directional_albedo(make_model(a), wo))(values)")


def _albedo(model, wo, opts) -> tuple[jax.Array, int]:
    if model.is_compound():  # Mixture, Scaled: sum_j scale_j E_j, lobe by lobe
        ch = model.channels()
        total, n_total = None, 0
        for scale, lobe in model.terms():
            e, n = _albedo(lobe, wo, opts)
            if ch is not None and lobe.channels() is None:
                e = expand_channels(e, ch)
            e = scale * e  # a Mixture's 1.0 leaves e bit for bit
            total = e if total is None else total + e
            n_total += n
        return total, n_total
    if model.is_delta:
        return model.delta_albedo(wo), 0
    rule = lobe_rule(model, wo, dtype=opts["dtype"], **opts["rule"])
    # Python-float parameters as (weakly typed) arrays: traced, not static, under filter_jit
    lobe = jax.tree_util.tree_map(lambda x: jnp.asarray(x) if isinstance(x, float) else x, model)
    return _rule_sum(lobe, rule.directions, rule.weights, wo), rule.n


def directional_albedo(
    model,
    wo,
    *,
    n_theta: int | None = None,
    n_phi: int = HALFVECTOR_N_PHI,
    generic: tuple[int, int] = (GENERIC_N_MU, GENERIC_N_PHI),
    return_n_evals: bool = False,
):
    """Directional albedo ``E(wo) = Int_H+ f(wi, wo) cos(theta_i) dwi`` of any registry model.

    By linearity, lobe by lobe, each with the rule suited to its type:

    ========================  ===================================================================
    ``MicrofacetBRDF``        :func:`halfvector_rule` at the distribution's widths (GGX, Beckmann:
                              ``alpha_x, alpha_y``; Blinn-Phong: ``sqrt(2/(n+2))``), ``n_theta x
                              n_phi`` evaluations (default 48 x 64 = 3072; 64 x 64 = 4096 for
                              Beckmann and Blinn-Phong)
    ``quadrature_lobe()``     the lobe's own request: ``("mirror", n)`` -> :func:`mirror_lobe_rule`
                              (Phong family, 16384 nodes, <= 15360 weighted), ``("half", width)`` ->
                              :func:`halfvector_rule` (Blinn-Phong), ``("mu", (mu, w))`` -> the
                              lobe's rule in mu x :func:`azimuthal_rule` (4 azimuths; the
                              Kulla-Conty lobe: 255 cells x 4 nodes x 4 = 4080 evaluations)
    ``Lambert``               :func:`cosine_rule` (2 x 2, exact)
    ``Mixture``               sum over its lobes; ``Scaled``: ``scale`` times the lobe's albedo
    delta lobes (``Mirror``)  their closed form ``model.albedo(wo)`` (0 evaluations)
    anything else             Gauss-Legendre in mu x trapezoid in phi, ``generic`` = (64, 128):
                              accurate for smooth lobes only
    ========================  ===================================================================

    Accuracy of the default on GGX with height-correlated Smith masking and F = 1: <= 3e-8
    absolute for alpha and cos(theta_o) in [1e-3, 1] (docs/quadrature.md).

    Args:
        model: a BRDF (:class:`~brdf_fit.models.AbstractBRDF`).
        wo: ``(..., 3)`` unit view directions.
        n_theta, n_phi: node counts of the microfacet rule (see :func:`halfvector_rule`);
            ``n_theta=None`` picks it by distribution (see :func:`lobe_rule`).
        generic: ``(n_mu, n_phi)`` of the fallback rule.
        return_n_evals: also return the number of BRDF evaluations per direction (int).

    Returns:
        ``E`` of shape ``(...,)`` or ``(..., C)`` like ``model.eval``; with ``return_n_evals``,
        ``(E, n_evals)``. Differentiable with respect to the model parameters (the rules are
        treated as fixed: their nodes depend on the lobe widths only through ``stop_gradient``).
    """
    wo = jnp.asarray(wo)
    if wo.shape[-1:] != (3,):
        raise ValueError(f"wo must have shape (..., 3), got {wo.shape}")
    _check_parameter_shapes(model)
    dtype = wo.dtype if jnp.issubdtype(wo.dtype, jnp.floating) else None
    if dtype == jnp.float32 and not isinstance(wo, jax.core.Tracer):
        # a concrete float32 call (under jit the caller chose its dtype): say what it costs
        warnings.warn(PrecisionWarning(
            "directional_albedo in float32: the quadrature sums thousands of terms and keeps "
            "about 3 digits (1.5e-3 measured on a 128 x 128 GGX albedo table, against 3e-8 in "
            "float64); enable float64 (jax.config.update('jax_enable_x64', True)) or pass "
            "float64 directions"), stacklevel=2)
    opts = {"dtype": dtype, "rule": {"n_theta": n_theta, "n_phi": n_phi, "generic": generic}}
    e, n = _albedo(model, wo, opts)
    return (e, n) if return_n_evals else e
