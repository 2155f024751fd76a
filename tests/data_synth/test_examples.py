"""The example recipes in examples/ synthesise, and the committed example data file is exactly
what its recipe produces (so the README's first commands work and the file cannot drift)."""

from pathlib import Path

import numpy as np
import pytest

from brdf_fit.io import read_csv
from data_synth.recipes import synthesize

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
RECIPES = sorted(p for p in EXAMPLES.iterdir() if p.suffix in (".toml", ".json"))


def test_there_are_examples():
    assert len(RECIPES) >= 3


@pytest.mark.parametrize("recipe", RECIPES, ids=lambda p: p.name)
def test_example_recipe_synthesises(recipe):
    data = synthesize(recipe)
    assert data.n > 0 and np.all(np.isfinite(data.value)) and np.all(data.value >= 0)


def test_committed_example_data_matches_its_recipe():
    committed = read_csv(EXAMPLES / "gold_4axis.csv")
    fresh = synthesize(EXAMPLES / "gold_4axis.toml")
    np.testing.assert_allclose(committed.wi, fresh.wi, rtol=0, atol=1e-12)
    np.testing.assert_allclose(committed.wo, fresh.wo, rtol=0, atol=1e-12)
    # the CSV stores values to 10 significant digits
    np.testing.assert_allclose(committed.value, fresh.value, rtol=1e-9, atol=0)
