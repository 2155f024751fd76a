"""brdf-fit lut dfg: writes the table (read back equal), --json metadata, and one-line errors
before any work for a bad size, masking, layout, channels or output path."""

from __future__ import annotations

import json

import numpy as np
import pytest
from _helpers import cli_one_error as one_error

from brdf_fit.cli import main
from brdf_fit.tables import read_table


def test_lut_dfg_writes_npz_and_json(tmp_path, capsys):
    out = tmp_path / "dfg.npz"
    code = main(["lut", "dfg", "--size", "8", "--masking", "karis", "-o", str(out), "--json",
                 "--quiet"])
    assert code == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["masking"] == "karis" and doc["size"] == 8 and doc["channels"] == ["A", "B"]
    assert doc["error_estimate"]["max_abs"] < 1e-7
    t = read_table(out)
    assert t.values.shape == (8, 8, 2) and t.meta["masking"] == "karis"
    assert (tmp_path / "dfg.json").exists()
    with np.load(out) as z:
        np.testing.assert_allclose(z["alpha"], z["roughness"] ** 2)


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["lut", "dfg", "--size", "8", "--masking", "smith"], "unknown masking"),
        (["lut", "dfg", "--size", "8", "--layout", "unity"], "unknown layout"),
        (["lut", "dfg", "--size", "8", "--channels", "A,E"], "--channels"),
        (["lut", "dfg", "--size", "5000"], "--size"),
        (["lut", "ibl"], "unknown table"),
        (["lut", "dfg", "--half"], "half precision"),
    ],
)
def test_bad_options_fail_before_work(tmp_path, capsys, argv, fragment):
    out = tmp_path / "t.npz"
    one_error(capsys, argv + ["-o", str(out)], fragment)
    assert not list(tmp_path.iterdir())


def test_bad_output_paths(tmp_path, capsys):
    one_error(capsys, ["lut", "dfg", "-o", str(tmp_path / "nope" / "t.npz")], "does not exist")
    one_error(capsys, ["lut", "dfg", "-o", str(tmp_path / "t.txt")], "unknown extension")
    one_error(capsys, ["lut", "dfg", "-o", str(tmp_path / "t.npz"), "--plot",
                       str(tmp_path / "p.txt")], "--plot")
    assert not list(tmp_path.iterdir())


def test_lut_albedo_and_eavg(tmp_path, capsys):
    out = tmp_path / "e.h"
    assert main(["lut", "albedo", "ggx", "--param", "f0=1", "--axis", "mu=3", "--axis",
                 "alpha=2", "-o", str(out), "--json", "--quiet"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["channels"] == ["E"] and [a["name"] for a in doc["axes"]] == ["mu", "alpha"]
    assert read_table(out).values.shape == (3, 2, 1)
    out2 = tmp_path / "avg.npz"
    assert main(["lut", "eavg", "lambert", "--axis", "rho=3:0.2:0.8", "--layout", "endpoints",
                 "-o", str(out2), "--quiet"]) == 0
    np.testing.assert_allclose(read_table(out2).values[..., 0], [0.2, 0.5, 0.8], rtol=1e-13)


@pytest.mark.parametrize("argv, fragment", [
    (["lut", "albedo", "--axis", "mu=4"], "needs a MODEL"),
    (["lut", "albedo", "ggx", "--axis", "alpha=4"], "--axis mu"),
    (["lut", "eavg", "ggx", "--axis", "mu=4"], "parameter axes only"),
    (["lut", "albedo", "ggx", "--axis", "mu=4", "--axis", "beta=2"], "unknown parameter"),
    (["lut", "albedo", "nope", "--axis", "mu=4"], "nope"),
    (["lut", "albedo", "ggx", "--axis", "mu=4", "--masking", "karis"], "lut dfg option"),
    (["lut", "dfg", "--axis", "mu=4"], "takes no MODEL"),
    (["lut", "albedo", "ggx", "--axis", "mu=4", "--axis", "alpha=3", "--axis", "f0=2",
      "-o", "PNG"], ".png holds 2-D tables"),
])
def test_bad_albedo_requests(tmp_path, capsys, argv, fragment):
    argv = [a.replace("PNG", str(tmp_path / "t.png")) for a in argv]
    if "-o" not in argv:
        argv += ["-o", str(tmp_path / "t.npz")]
    one_error(capsys, argv, fragment)
    assert not list(tmp_path.iterdir())


def test_compilation_cache_folder(monkeypatch, tmp_path):
    """The persistent compilation cache: $BRDF_FIT_CACHE_DIR, else XDG; off with
    BRDF_FIT_NO_CACHE=1 (set for the whole suite) and with --no-cache."""
    from brdf_fit import cli

    monkeypatch.setenv("BRDF_FIT_NO_CACHE", "0")
    monkeypatch.setenv("BRDF_FIT_CACHE_DIR", str(tmp_path / "c"))
    assert cli.cache_dir() == str(tmp_path / "c")
    monkeypatch.delenv("BRDF_FIT_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert cli.cache_dir() == str(tmp_path / "brdf_fit" / "jax")
    monkeypatch.setenv("BRDF_FIT_NO_CACHE", "1")
    assert cli.cache_dir() is None
    assert cli.build_parser().parse_args(["--no-cache", "models"]).no_cache
