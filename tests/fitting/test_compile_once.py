"""Compile once (issue 41): fits of new sizes within a sample-count bucket reuse the programs
compiled for the first, in one process. The count is XLA's own (``jax.monitoring``'s backend
compile events), so any new program, whatever compiled it, fails the test."""

import jax
import numpy as np
from _helpers import counting_compiles, random_dirs

from brdf_fit import registry
from brdf_fit.data import GonioData
from brdf_fit.fitting.single import fit
from brdf_fit.fitting.solvers import dense_bucket


def _data(n, seed):
    rng = np.random.default_rng(seed)
    wi, wo = random_dirs(rng, n), random_dirs(rng, n)
    f = np.asarray(registry.get("ggx").build(alpha=0.3, f0=0.6).eval(wi, wo))
    return GonioData(wi, wo, f[:, None] * rng.lognormal(0.0, 0.01, (n, 1)))


def test_a_new_size_in_the_same_bucket_compiles_nothing():
    # one bucket of the dense path (2 per octave: 385..512 pad to 512), the sizes of a file
    # and of one with 90% of its samples (benchmarks/bench_compiles.py, fit-again)
    sizes = (490, 505, 441)
    assert len({dense_bucket(n) for n in sizes}) == 1
    first = fit(_data(sizes[0], 0), "ggx")  # compiles what it needs (or finds it compiled)
    assert first.converged
    for k, n in enumerate(sizes[1:], 1):
        data = _data(n, k)  # (its own eager evaluation compiles: outside the count)
        with counting_compiles() as compiled:
            r = fit(data, "ggx")
        assert r.converged and r.n_samples == n
        assert compiled == [], (f"a fit of {n} samples after one of {sizes[0]} compiled "
                                f"{len(compiled)} program(s) ({sum(compiled):.2f} s)")


def test_the_counter_sees_a_new_program():
    """The negative control: a program never compiled before is counted."""
    with counting_compiles() as compiled:
        jax.jit(lambda x: x * 3.0 + 1.25)(np.ones(7))
    assert len(compiled) == 1
