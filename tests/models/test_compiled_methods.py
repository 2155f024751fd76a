"""A built model's public ``eval``, ``pdf`` and ``sample`` run as one compiled program when
called outside a JAX trace, and as written inside one (issue 44;
:func:`brdf_fit.models._base.compiled_outside_traces`). Programs are counted by XLA's own
compile events (``_helpers.counting_compiles``), so the negative control, the method called
op by op, shows that the counter tells the two apart."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import counting_compiles, random_dirs

from brdf_fit import registry
from brdf_fit.models import AbstractBRDF

#: the model of the issue's evaluation benchmark (complex Fresnel: the most operations)
ENTRY = "ggx-conductor"


def _dirs(n, seed):
    rng = np.random.default_rng(seed)
    return random_dirs(rng, n), random_dirs(rng, n)


def test_every_model_class_has_its_methods_compiled():
    def subclasses(cls):
        for sub in cls.__subclasses__():
            yield sub
            yield from subclasses(sub)

    classes = list(subclasses(AbstractBRDF))
    assert len(classes) > 20
    for cls in classes:
        for name in ("eval", "pdf", "sample"):
            method = getattr(cls, name)
            if getattr(method, "__isabstractmethod__", False):
                continue  # an abstract base between AbstractBRDF and its models
            assert hasattr(method, "raw"), f"{cls.__name__}.{name}"


def test_an_eager_eval_pdf_and_sample_are_one_program_each():
    entry = registry.get(ENTRY)
    m = entry.build(alpha=0.27)  # a Python float: a traced argument, not a constant
    wi, wo = _dirs(53, 0)  # a size no other test uses: the programs are new
    uc, u = np.full(53, 0.4), np.full((53, 2), 0.3)
    for call in (lambda: m.eval(wi, wo), lambda: m.pdf(wi, wo), lambda: m.sample(wo, uc, u)):
        with counting_compiles() as compiled:
            jax.block_until_ready(call())
        assert len(compiled) == 1, f"{len(compiled)} programs"
    # other parameter values, Python floats included: the same program
    with counting_compiles() as compiled:
        for a in (0.05, 0.3, 0.9):
            jax.block_until_ready(entry.build(alpha=a).eval(wi, wo))
        jax.block_until_ready(entry.build(alpha=jnp.asarray(0.4)).eval(wi, wo))
    assert compiled == []


def test_the_counter_sees_a_method_run_op_by_op():
    """The negative control: the method as written, called eagerly, dispatches its operations
    one by one, each a program of its own."""
    m = registry.get(ENTRY).build()
    wi, wo = _dirs(59, 1)
    with counting_compiles() as compiled:
        jax.block_until_ready(type(m).eval.raw(m, wi, wo))
    assert len(compiled) > 10


@pytest.mark.parametrize("name", [ENTRY, "lambert", "phong", "oren-nayar"])
def test_compiled_equals_op_by_op(name):
    entry = registry.get(name)
    m = entry.build()
    wi, wo = _dirs(64, 2)
    f = np.asarray(m.eval(wi, wo))
    ref = np.asarray(type(m).eval.raw(m, wi, wo))
    # to rounding, relative to the largest value (a compiled program may contract a*b + c into
    # a fused multiply-add where the operations one by one round twice)
    eps = np.finfo(f.dtype).eps
    np.testing.assert_allclose(f, ref, rtol=16 * eps, atol=16 * eps * float(np.abs(ref).max()))
    np.testing.assert_allclose(np.asarray(m.pdf(wi, wo)), np.asarray(type(m).pdf.raw(m, wi, wo)),
                               rtol=16 * eps, atol=0)


def test_inside_a_trace_the_method_is_traced_as_written():
    entry = registry.get(ENTRY)
    wi, wo = _dirs(32, 3)

    def total(a):
        return jnp.sum(entry.build(alpha=a).eval(wi, wo))

    g = float(jax.grad(total)(0.3))
    h = 1e-5
    fd = (float(total(0.3 + h)) - float(total(0.3 - h))) / (2 * h)
    assert g == pytest.approx(fd, rel=1e-7)
    # a batch of models (vmap) and a jit around the call
    alphas = jnp.asarray([0.1, 0.2, 0.4])
    batch = jax.vmap(lambda a: entry.build(alpha=a).eval(wi, wo))(alphas)
    assert batch.shape == (3, 32, 3)
    np.testing.assert_allclose(batch[1], entry.build(alpha=0.2).eval(wi, wo), rtol=1e-12)
    # the traced call puts the model's operations in the caller's program, not a compiled
    # call of its own (equinox.filter_jit's program is named after the method)
    jaxpr = jax.make_jaxpr(lambda a: entry.build(alpha=a).eval(wi, wo))(0.3)
    names = [e.params.get("name") for e in jaxpr.jaxpr.eqns]
    assert "eval" not in names
    m = entry.build(alpha=0.3)  # the control: no traced leaf, so the compiled call
    eager = jax.make_jaxpr(lambda: m.eval(wi, wo))()
    assert "eval" in [e.params.get("name") for e in eager.jaxpr.eqns]
