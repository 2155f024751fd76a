"""Weighted sums of lobes with one-sample lobe selection.

``f = sum_j f_j``; a sample first picks lobe ``j`` with probability ``p_j`` proportional to the
lobe's :meth:`~brdf_fit.models.AbstractBRDF.selection_hint` (how much it reflects), then samples
that lobe; the reported pdf is the mixture density ``sum_j p_j pdf_j`` (one-sample MIS with the
balance heuristic: E. Veach, L. Guibas, "Optimally combining sampling techniques for Monte Carlo
rendering", SIGGRAPH 1995, section 5). The lobe-choice uniform is rescaled to [0, 1) and passed on,
so a lobe may use it for its own discrete choices.
"""

from __future__ import annotations

import jax.numpy as jnp

from brdf_fit.core.params import Scalar, bounded
from brdf_fit.core.validate import check_param
from brdf_fit.models._base import AbstractBRDF, BRDFSample, expand_channels
from brdf_fit.models._lobes import finish_sample, max_over_channels


class Scaled(AbstractBRDF):
    """``scale * lobe`` (e.g. the ``ks`` of Torrance-Sparrow). Same sampler and pdf as the lobe."""

    lobe: AbstractBRDF
    scale: Scalar = bounded(1.0, lo=0.0, hi=1.0)

    def __check_init__(self):
        check_param("scale", self.scale, lo=0.0, owner="Scaled")

    def eval(self, wi, wo):
        return self.scale * self.lobe.eval(wi, wo)

    def pdf(self, wi, wo):
        return self.lobe.pdf(wi, wo)

    def sample(self, wo, uc, u):
        s = self.lobe.sample(wo, uc, u)
        return BRDFSample(wi=s.wi, pdf=s.pdf, weight=self.scale * s.weight)

    def selection_hint(self):
        return max_over_channels(self.scale) * self.lobe.selection_hint()

    @property
    def is_delta(self):  # type: ignore[override]
        return self.lobe.is_delta

    def prepared(self):
        return Scaled(lobe=self.lobe.prepared(), scale=self.scale)

    def terms(self):
        return ((self.scale, self.lobe),)

    def pdf_terms(self):
        return ((1.0, self.lobe),)

    def is_compound(self) -> bool:
        return True

    def is_anisotropic(self) -> bool:
        return self.lobe.is_anisotropic()


class Mixture(AbstractBRDF):
    """Sum of non-delta lobes, sampled by one-sample lobe selection (see the module docstring)."""

    lobes: tuple[AbstractBRDF, ...]

    def __check_init__(self):
        if len(self.lobes) == 0:
            raise ValueError("Mixture needs at least one lobe")
        for lobe in self.lobes:
            if lobe.is_delta:
                raise ValueError(
                    "a delta lobe cannot be mixed with one-sample selection and a summed pdf; "
                    "sample it separately"
                )

    def eval(self, wi, wo):
        ch = self.channels()
        out = 0.0
        for lobe in self.lobes:
            f = lobe.eval(wi, wo)
            out = out + (expand_channels(f, ch) if lobe.channels() is None else f)
        return out

    def probabilities(self):
        """Lobe-selection probabilities, shape (n_lobes,)."""
        h = jnp.stack([jnp.maximum(lobe.selection_hint(), 0.0) for lobe in self.lobes])
        total = jnp.sum(h)
        n = len(self.lobes)
        return jnp.where(total > 0, h / jnp.where(total > 0, total, 1.0), 1.0 / n)

    def pdf(self, wi, wo):
        p = self.probabilities()
        return sum(p[j] * lobe.pdf(wi, wo) for j, lobe in enumerate(self.lobes))

    def sample(self, wo, uc, u):
        p = self.probabilities()
        cdf = jnp.cumsum(p)
        n = len(self.lobes)
        idx = jnp.minimum(jnp.sum(uc[..., None] >= cdf[:-1], axis=-1), n - 1) if n > 1 else (
            jnp.zeros(jnp.shape(uc), dtype=jnp.int32)
        )
        lo = jnp.concatenate([jnp.zeros((1,), p.dtype), cdf[:-1]])[idx]
        pj = p[idx]
        uc2 = jnp.clip((uc - lo) / jnp.where(pj > 0, pj, 1.0), 0.0, 1.0 - 1e-7)
        wi = None
        for j, lobe in enumerate(self.lobes):
            s = lobe.sample(wo, uc2, u)
            wi = s.wi if wi is None else jnp.where((idx == j)[..., None], s.wi, wi)
        return finish_sample(self, wi, wo)

    def selection_hint(self):
        return sum(lobe.selection_hint() for lobe in self.lobes)

    def prepared(self):
        return Mixture(lobes=tuple(lobe.prepared() for lobe in self.lobes))

    def terms(self):
        return tuple((1.0, lobe) for lobe in self.lobes)

    def pdf_terms(self):
        p = self.probabilities()
        return tuple((p[j], lobe) for j, lobe in enumerate(self.lobes))

    def is_compound(self) -> bool:
        return True

    def is_anisotropic(self) -> bool:
        return any(lobe.is_anisotropic() for lobe in self.lobes)
