"""BRDF models. Each class holds eval, pdf and sample together; see :mod:`._base` for the
conventions every model follows."""

from brdf_fit.models._base import AbstractBRDF, BRDFSample, QuadratureLobe, astype, n_channels
from brdf_fit.models.lambert import Lambert
from brdf_fit.models.microfacet_brdf import MicrofacetBRDF
from brdf_fit.models.mirror import Mirror
from brdf_fit.models.mixture import Mixture, Scaled

__all__ = [
    "AbstractBRDF",
    "BRDFSample",
    "Lambert",
    "MicrofacetBRDF",
    "Mirror",
    "Mixture",
    "QuadratureLobe",
    "Scaled",
    "astype",
    "n_channels",
]
