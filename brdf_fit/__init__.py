"""brdf_fit: a differentiable BRDF toolkit in pure JAX.

The public API is what this module re-exports; everything else is private. Conventions (frame,
directions, eval without cosine, pdf, sample with uniforms, channels, dtype, units) are written
in :mod:`brdf_fit.models._base` and in the README.
"""

from . import fresnel, microfacet, registry
from ._validate import ParameterError
from .convert import alpha_to_roughness, roughness_to_alpha
from .models import (
    AbstractBRDF,
    BRDFSample,
    Lambert,
    MicrofacetBRDF,
    Mirror,
    Mixture,
    Scaled,
    astype,
)

__version__ = "0.1.0"

__all__ = [
    "AbstractBRDF",
    "BRDFSample",
    "Lambert",
    "MicrofacetBRDF",
    "Mirror",
    "Mixture",
    "ParameterError",
    "Scaled",
    "alpha_to_roughness",
    "astype",
    "fresnel",
    "microfacet",
    "registry",
    "roughness_to_alpha",
    "__version__",
]
