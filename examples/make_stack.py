"""Writes examples/stack/: a synthetic image stack to try ``brdf-fit fit-batch --images`` on.

A 16 x 16 GGX texture (alpha from 0.08 on the left to 0.48 on the right; f0 from blue-ish at the
top to red-ish at the bottom), photographed by the virtual gonioreflectometer under 24 random
light/view pairs (``random_sparse``, seed 3, zeniths up to 70 degrees), 1% lognormal noise
(seed 7), as 24 OpenEXR images and ``stack.json``. Run from the repository root:

    python examples/make_stack.py
"""

import pathlib
import shutil

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

from data_synth.plans import make_plan  # noqa: E402
from data_synth.stack import synth_stack  # noqa: E402

N = 16
yy, xx = np.mgrid[0:N, 0:N] / (N - 1)
ALPHA = 0.08 + 0.4 * xx
F0 = np.stack([0.2 + 0.6 * yy, 0.5 + 0 * yy, 0.9 - 0.6 * yy], -1)

if __name__ == "__main__":
    out = pathlib.Path(__file__).with_name("stack")
    shutil.rmtree(out, ignore_errors=True)
    plan = make_plan("random_sparse", {"n": 24, "seed": 3, "max_zenith_deg": 70})
    print(synth_stack(out, "ggx", {"alpha": ALPHA, "f0": F0}, plan, seed=7, noise_sigma=0.01))
