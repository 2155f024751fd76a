"""Exported solver programs kept between processes (brdf_fit.fitting._export, issue 15): the
exported path gives exactly the plain jitted path's FitResult, a changed package source hash
never reuses a program, and a corrupt cache file falls back cleanly (re-exported). The cache
checks run on a small jitted function (the logic is the same for every program): cheap."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from brdf_fit import registry
from brdf_fit.data import GonioData
from brdf_fit.fitting import _export, single


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(3)

    def dirs(n):
        mu = rng.uniform(0.1, 1.0, n)
        phi = rng.uniform(0, 2 * np.pi, n)
        s = np.sqrt(1 - mu * mu)
        return np.stack([s * np.cos(phi), s * np.sin(phi), mu], -1)

    wi, wo = dirs(60), dirs(60)
    m = registry.get("ggx").build(alpha=0.3, f0=[0.9, 0.6, 0.3])
    v = np.asarray(m.eval(jnp.asarray(wi), jnp.asarray(wo)))
    v = v * np.exp(0.01 * rng.standard_normal(v.shape))
    return GonioData(wi=wi, wo=wo, value=v, channels=("R", "G", "B"))


def _fit(data):
    single._JITTED.clear()  # a fresh process: no compiled problem in memory
    res = single.fit(data, "ggx", init={"alpha": 0.5})
    stats = {"loaded": 0, "exported": 0, "fallback": 0}
    for jitted in single._JITTED.values():
        for f in (jitted.run, jitted.per_channel, jitted.finish):
            for k in stats:
                stats[k] += f.stats[k]
    return res, stats


def _same(a, b):
    da, db = a.to_dict(), b.to_dict()
    da.pop("seconds"), db.pop("seconds")
    assert da == db  # every number bit for bit (floats compare exactly)
    for k in a.params:
        np.testing.assert_array_equal(np.asarray(a.params[k]), np.asarray(b.params[k]))


def test_exported_path_equals_plain(data, tmp_path, monkeypatch):
    monkeypatch.delenv(_export.ENV, raising=False)
    monkeypatch.setattr(single, "_JITTED", {})
    plain, stats = _fit(data)
    assert stats == {"loaded": 0, "exported": 0, "fallback": 0}  # off without the folder

    folder = tmp_path / "exported"
    monkeypatch.setenv(_export.ENV, str(folder))
    first, stats = _fit(data)  # exports the three programs and runs them
    assert stats == {"loaded": 0, "exported": 3, "fallback": 0}
    assert len(list(folder.rglob("*.bin"))) == 3
    _same(plain, first)

    second, stats = _fit(data)  # a warm process: loads them, traces no model code
    assert stats == {"loaded": 3, "exported": 0, "fallback": 0}
    _same(plain, second)


def _call(folder, static="k"):
    """A fresh ExportedCall of a small jitted function (a new process's), called once."""
    f = _export.ExportedCall(jax.jit(lambda x, a: (x * a[0] + a[1], {"s": jnp.sum(x)})),
                             "tiny", static)
    x = np.arange(5.0)
    out = f(x, (np.float64(2.0), 1.5))
    np.testing.assert_array_equal(np.asarray(out[0]), x * 2.0 + 1.5)
    assert float(out[1]["s"]) == 10.0
    return f.stats


def test_stale_and_corrupt_programs_are_never_used(tmp_path, monkeypatch):
    folder = tmp_path / "exported"
    monkeypatch.setenv(_export.ENV, str(folder))
    assert _call(folder) == {"loaded": 0, "exported": 1, "fallback": 0}
    assert _call(folder) == {"loaded": 1, "exported": 0, "fallback": 0}
    (path,) = folder.rglob("tiny-*.bin")
    good = path.read_bytes()

    # corrupt files (truncated; a flipped byte; a valid checksum over garbage) are ignored and
    # rewritten
    flipped = bytearray(good)
    flipped[-10] ^= 0xFF
    import hashlib
    garbage = _export._MAGIC + hashlib.sha256(b"garbage").digest() + b"garbage"
    for bad in (good[:40], bytes(flipped), garbage, b""):
        path.write_bytes(bad)
        assert _call(folder) == {"loaded": 0, "exported": 1, "fallback": 0}
        assert _export._read(str(path), 3) is not None  # rewritten, whole
    assert _call(folder) == {"loaded": 1, "exported": 0, "fallback": 0}

    # another package source (an edited module): another file, the old one is not read
    monkeypatch.setattr(_export, "_SOURCE_HASH", "0" * 64)
    assert _call(folder) == {"loaded": 0, "exported": 1, "fallback": 0}
    assert len(list(folder.rglob("tiny-*.bin"))) == 2
    # another static key (another problem): another file too
    assert _call(folder, "other") == {"loaded": 0, "exported": 1, "fallback": 0}
    assert len(list(folder.rglob("tiny-*.bin"))) == 3


def test_outputs_fed_back_reuse_the_program(tmp_path, monkeypatch):
    """An exported program's outputs are committed arrays; fed back into it (as a solver's
    iterate is), they must not make jax.jit lower the program a second time (the chunked fit
    loaded each of its programs twice before the arguments were committed, issue 44)."""
    from tests._helpers import counting_compiles

    monkeypatch.setenv(_export.ENV, str(tmp_path / "exported"))
    f = _export.ExportedCall(jax.jit(lambda x: x * 0.5 + 1.0), "feedback", "k")
    x = jnp.asarray(np.arange(4.0))  # made by jnp.asarray: not committed
    assert not x.committed
    y = f(x)
    assert y.committed
    with counting_compiles() as seen:
        z = f(f(y))
    assert seen == []
    np.testing.assert_allclose(np.asarray(z), ((np.arange(4.0) * 0.5 + 1) * 0.5 + 1) * 0.5 + 1)


def test_old_generations_and_the_flat_layout_are_pruned(tmp_path, monkeypatch):
    """Programs of other package sources or JAX versions can never be used again: writing a
    program keeps the current generation and the KEEP_GENERATIONS - 1 most recently used
    others, deletes the flat layout's files, and leaves every name it did not write."""
    import os

    folder = tmp_path / "exported"
    monkeypatch.setenv(_export.ENV, str(folder))
    folder.mkdir()
    old = []
    for i in range(5):  # five earlier generations, gen 0 the oldest
        g = folder / f"gen-{i:016x}"
        g.mkdir()
        (g / f"tiny-{'a' * 40}.bin").write_bytes(b"x" * 100)
        os.utime(g, (1000.0 + i, 1000.0 + i))
        old.append(g)
    flat = folder / f"fit_run-{'b' * 40}.bin"  # the layout before generations
    flat.write_bytes(b"y")
    (folder / ".tmp-abc").write_bytes(b"z")  # an interrupted write
    keep = [folder / "notes.txt", folder / "gen-not-ours", folder / "mine.bin"]
    keep[0].write_text("a user's file")
    keep[1].mkdir()
    keep[2].write_bytes(b"w")

    assert _call(folder) == {"loaded": 0, "exported": 1, "fallback": 0}
    gens = sorted(p.name for p in folder.glob("gen-????????????????"))
    current = _export.generation()
    # the current one and the two most recently used of the others (gens 4 and 3)
    assert gens == sorted([current, old[4].name, old[3].name])
    assert _export.KEEP_GENERATIONS == 3
    assert not flat.exists() and not (folder / ".tmp-abc").exists()
    assert all(p.exists() for p in keep)
    # loading marks the generation as used, and a load prunes nothing
    assert _call(folder) == {"loaded": 1, "exported": 0, "fallback": 0}
    assert (folder / current).stat().st_mtime > old[4].stat().st_mtime
    # a folder that cannot be listed: nothing removed, no error
    assert _export.prune(str(tmp_path / "missing")) == []


def test_no_folder_unwritable_folder_or_no_key_use_the_plain_path(tmp_path, monkeypatch):
    monkeypatch.delenv(_export.ENV, raising=False)
    assert _call(None) == {"loaded": 0, "exported": 0, "fallback": 0}
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    monkeypatch.setenv(_export.ENV, str(blocker / "exported"))  # cannot be created
    assert _call(None) == {"loaded": 0, "exported": 0, "fallback": 1}
    monkeypatch.setenv(_export.ENV, str(tmp_path / "exported"))
    assert _call(None, static=None) == {"loaded": 0, "exported": 0, "fallback": 0}
    assert not (tmp_path / "exported").exists()


def test_only_package_registry_models_are_cached():
    from brdf_fit.fitting.problem import FitProblem

    problem = FitProblem.of("ggx", n_channels=3)
    key = (problem.key, (), 3, "lm", 1e-10, 1e-10, 256)
    assert _export.export_key(problem, key) == repr(key)
    built = FitProblem.of(registry.get("ggx").build(alpha=0.3, f0=[0.9, 0.6, 0.3]))
    assert _export.export_key(built, (built.key, (), 3, "lm", 1e-10, 1e-10, 256)) is None
