"""The registry's gold default (effective RGB eta, k) is stored in resources/gold_rgb_nk.json so
that building a gold model does not import colour-science and refit; the file must equal the
live computation (brdf_fit.core.spectra.rgb_nk). To regenerate after a change to spectra:
write spectra.rgb_nk("Au") into the file's "eta" and "k"."""

import json

import numpy as np

from brdf_fit import registry
from brdf_fit.core import spectra


def test_stored_gold_default_equals_the_live_computation():
    doc = json.loads(registry.GOLD_RGB_NK_FILE.read_text())
    eta, k = spectra.rgb_nk("Au")
    np.testing.assert_allclose(doc["eta"], eta, rtol=1e-10)
    np.testing.assert_allclose(doc["k"], k, rtol=1e-10)
    d = registry.get("ggx-conductor").defaults()
    np.testing.assert_array_equal(d["eta"], doc["eta"])
    np.testing.assert_array_equal(d["k"], doc["k"])
