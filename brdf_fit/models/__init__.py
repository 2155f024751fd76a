"""BRDF models. Each class holds eval, pdf and sample together; see :mod:`._base` for the
conventions every model follows."""

from brdf_fit.models._base import AbstractBRDF, BRDFSample, QuadratureLobe, astype, n_channels
from brdf_fit.models.kulla_conty import KullaContyLobe
from brdf_fit.models.lambert import Lambert
from brdf_fit.models.microfacet_brdf import MicrofacetBRDF
from brdf_fit.models.mirror import Mirror
from brdf_fit.models.mixture import Mixture, Scaled
from brdf_fit.models.turquin import TurquinCompensated

__all__ = [
    "AbstractBRDF",
    "BRDFSample",
    "KullaContyLobe",
    "Lambert",
    "MicrofacetBRDF",
    "Mirror",
    "Mixture",
    "QuadratureLobe",
    "Scaled",
    "TurquinCompensated",
    "astype",
    "n_channels",
]
