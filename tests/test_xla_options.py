"""brdf_fit._xla: the XLA option the command line and the tests run with is appended only where it
can act and is wanted: never over the user's own setting of it, never with the opt-out, never
for a jaxlib series where it was not verified (XLA aborts on a flag it does not know), and
never once JAX is imported."""

import pytest

from brdf_fit import _xla


@pytest.fixture
def verified(monkeypatch):
    monkeypatch.setattr(_xla, "_jaxlib_series", lambda: next(iter(_xla.VERIFIED)))


def test_appended_to_the_users_flags(verified):
    env = {"XLA_FLAGS": "--xla_cpu_max_isa=AVX2"}
    assert _xla.configure(env)
    assert env["XLA_FLAGS"] == f"--xla_cpu_max_isa=AVX2 {_xla.FLAG}"
    env = {}
    assert _xla.configure(env) and env["XLA_FLAGS"] == _xla.FLAG


@pytest.mark.parametrize("env", [
    {"XLA_FLAGS": "--xla_cpu_use_fusion_emitters=true"},  # the user's choice stands
    {_xla.OPT_OUT_ENV: "0"},
])
def test_left_alone(verified, env):
    before = dict(env)
    assert not _xla.configure(env)
    assert env == before


def test_not_for_an_unverified_jaxlib(monkeypatch):
    for series in [(0, 99), None]:
        monkeypatch.setattr(_xla, "_jaxlib_series", lambda series=series: series)
        env = {}
        assert not _xla.configure(env) and env == {}


def test_too_late_once_jax_is_imported(verified, monkeypatch):
    import jax  # noqa: F401  (imported by the test session anyway)

    monkeypatch.setenv("XLA_FLAGS", "")
    assert not _xla.configure()  # the process's own environment, JAX already started
    import os

    assert os.environ["XLA_FLAGS"] == ""
