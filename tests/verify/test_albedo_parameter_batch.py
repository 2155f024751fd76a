"""A batch axis on a model parameter (issue 16): ``directional_albedo`` builds its quadrature
rule for one lobe, so a GGX width of shape (N, 1) against views of shape (N, N, 3) returned an
(N, N, 1) array with values up to 18 for an albedo <= 1. It is refused, naming the parameter and
the way to batch (jax.vmap over models); channel parameters keep their 1-D channel axis."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from brdf_fit import MicrofacetBRDF
from brdf_fit.core.fresnel import ConstantFresnel, SchlickFresnel
from brdf_fit.core.microfacet import GGX, SmithHeightCorrelated
from brdf_fit.core.validate import ParameterError
from brdf_fit.verify.albedo import directional_albedo

N = 4
ALPHA = jnp.linspace(0.1, 0.9, N)
THETA = jnp.linspace(0.1, 1.4, N)
WO = jnp.broadcast_to(jnp.stack([jnp.sin(THETA), 0.0 * THETA, jnp.cos(THETA)], -1)[None],
                      (N, N, 3))


def lobe(alpha, fresnel=None):
    return MicrofacetBRDF(GGX(alpha), SmithHeightCorrelated(),
                          ConstantFresnel(1.0) if fresnel is None else fresnel)


def test_batched_geometric_parameter_is_refused_with_its_name():
    with pytest.raises(ParameterError, match=r"alpha_x.*shape \(4, 1\).*jax\.vmap"):
        directional_albedo(lobe(ALPHA[:, None]), WO)
    with pytest.raises(ParameterError, match="alpha_x"):
        directional_albedo(lobe(ALPHA), WO[0])  # a 1-D width is no channel vector either


def test_vmap_over_models_gives_the_per_model_albedo():
    e = jax.vmap(lambda a, w: directional_albedo(lobe(a), w))(ALPHA, WO)
    assert e.shape == (N, N)
    # the vmapped and the single call compile to different fusions (summation order): they
    # agree to rounding (measured 3.7e-16 relative); 1e-14 is ~50 ulps
    for i in (0, N - 1):  # the first and last rows (each single call is an eager quadrature)
        np.testing.assert_allclose(np.asarray(e[i]),
                                   np.asarray(directional_albedo(lobe(ALPHA[i]), WO[i])),
                                   rtol=1e-14, atol=0)
    # F = 1: energy is lost to masking, never gained (the refused call gave up to 18)
    assert float(jnp.max(e)) <= 1.0


def test_channel_parameter_keeps_its_channel_axis():
    e = directional_albedo(lobe(0.3, SchlickFresnel(f0=jnp.asarray([0.9, 0.6, 0.3]))), WO[0])
    assert e.shape == (N, 3) and bool(jnp.all((e > 0) & (e <= 1)))
