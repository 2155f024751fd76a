"""Layer 3: is a model physically plausible and its sampler right? ``albedo`` (directional albedo
lobe by lobe), ``checks`` (the named checks, ``run_checks``, negative controls), ``chi2`` (sampler
against pdf), ``catalogue`` (the Montes & Urena table generated from the registry)."""
