"""BRDF models. Each class holds eval, pdf and sample together; see :mod:`._base` for the
conventions every model follows."""

from ._base import AbstractBRDF, BRDFSample, astype, n_channels
from .lambert import Lambert
from .microfacet_brdf import MicrofacetBRDF
from .mirror import Mirror
from .mixture import Mixture, Scaled

__all__ = [
    "AbstractBRDF",
    "BRDFSample",
    "Lambert",
    "MicrofacetBRDF",
    "Mirror",
    "Mixture",
    "Scaled",
    "astype",
    "n_channels",
]
