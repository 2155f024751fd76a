"""Negative controls: models that wrap a model and break one property on purpose (the pdf
scaled, reciprocity, energy, the sampler's weights, the sampler's distribution), so that each
check of :mod:`brdf_fit.verify.checks` is shown to fail where it must (tests/verify/test_checks.py,
tests/verify/test_chi2.py).
"""

from __future__ import annotations

from brdf_fit.models._base import AbstractBRDF
from brdf_fit.models._lobes import sample_weight

__all__ = ["AbstractNegativeControl", "PdfScaled", "NonReciprocal", "Overbright",
           "OverweightSampler", "DriftingSampler"]


class AbstractNegativeControl(AbstractBRDF):
    """A model that wraps a model ``inner`` (a field of each concrete control) and breaks one
    property on purpose (abstract)."""


class PdfScaled(AbstractNegativeControl):
    """Negative control: reports ``factor * pdf`` (sampler unchanged)."""

    inner: AbstractBRDF
    factor: float = 1.1

    def eval(self, wi, wo):
        return self.inner.eval(wi, wo)

    def pdf(self, wi, wo):
        return self.factor * self.inner.pdf(wi, wo)

    def sample(self, wo, uc, u):
        s = self.inner.sample(wo, uc, u)
        return type(s)(wi=s.wi, pdf=self.factor * s.pdf, weight=s.weight / self.factor)


class NonReciprocal(AbstractNegativeControl):
    """Negative control: ``f * (1 + strength (cos_i - cos_o))`` (positive, not symmetric)."""

    inner: AbstractBRDF
    strength: float = 0.3

    def eval(self, wi, wo):
        g = 1.0 + self.strength * (wi[..., 2] - wo[..., 2])
        f = self.inner.eval(wi, wo)
        return f * (g if f.ndim == g.ndim else g[..., None])

    def pdf(self, wi, wo):
        return self.inner.pdf(wi, wo)

    def sample(self, wo, uc, u):

        s = self.inner.sample(wo, uc, u)
        return type(s)(wi=s.wi, pdf=s.pdf, weight=sample_weight(self, s.wi, wo, s.pdf))


class Overbright(AbstractNegativeControl):
    """Negative control: ``factor * f`` with the same sampler (reflects more than it receives)."""

    inner: AbstractBRDF
    factor: float = 1.25

    def eval(self, wi, wo):
        return self.factor * self.inner.eval(wi, wo)

    def pdf(self, wi, wo):
        return self.inner.pdf(wi, wo)

    def sample(self, wo, uc, u):
        s = self.inner.sample(wo, uc, u)
        return type(s)(wi=s.wi, pdf=s.pdf, weight=self.factor * s.weight)


class OverweightSampler(AbstractNegativeControl):
    """Negative control: ``sample`` returns ``factor`` times the correct weight (eval and pdf
    untouched): a sampler whose weights are biased, also when they have no variance."""

    inner: AbstractBRDF
    factor: float = 1.0001

    def eval(self, wi, wo):
        return self.inner.eval(wi, wo)

    def pdf(self, wi, wo):
        return self.inner.pdf(wi, wo)

    def sample(self, wo, uc, u):
        s = self.inner.sample(wo, uc, u)
        return type(s)(wi=s.wi, pdf=s.pdf, weight=self.factor * s.weight)


class DriftingSampler(AbstractNegativeControl):
    """Negative control: draws with ``u0 -> u0^(1 + drift)`` but reports the inner pdf and the
    weight computed from it, i.e. a sampler that drifted off its pdf."""

    inner: AbstractBRDF
    drift: float = 0.1

    def eval(self, wi, wo):
        return self.inner.eval(wi, wo)

    def pdf(self, wi, wo):
        return self.inner.pdf(wi, wo)

    def sample(self, wo, uc, u):

        u = u.at[..., 0].set(u[..., 0] ** (1.0 + self.drift))
        s = self.inner.sample(wo, uc, u)
        pdf = self.inner.pdf(s.wi, wo)
        return type(s)(wi=s.wi, pdf=pdf, weight=sample_weight(self, s.wi, wo, pdf))
