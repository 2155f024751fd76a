"""Layer 0: the numerics and physics every model shares, with no import from anything above.

``numerics`` (safe functions, named epsilons), ``validate`` (parameter errors), ``params``
(``Param``/``Entry``: what models declare), ``frame`` and ``warp`` (directions and sampling
warps), ``special`` (betainc with shape derivatives), ``fresnel`` and ``spectra`` (spectra
imports fresnel, not back), ``microfacet`` (distributions and masking), ``phong_normaliser``
and ``quadrature`` (rules only; no model).
"""
