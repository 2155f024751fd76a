"""A data file may hold BRDF values up to brdf_fit.data.MAX_VALUE in magnitude; one value of
1e300 used to be accepted, overflow the fit's normal equations and hang in an SVD (issue 16,
defect 7). It is now refused when the file is read, naming the file and the sample."""

from pathlib import Path

import numpy as np
import pytest

from brdf_fit.cli import main
from brdf_fit.data import MAX_VALUE, DataError, GonioData
from brdf_fit.io import read

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "gold_4axis.csv"


def _with_value(tmp_path, value: str) -> Path:
    lines = EXAMPLE.read_text(encoding="utf-8").splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("theta_i")) + 3
    cols = lines[k].split(",")
    cols[4] = value  # brdf_r of the third data row
    lines[k] = ",".join(cols)
    p = tmp_path / "huge.csv"
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return p


def test_largest_value_is_stated_and_physical():
    # a GGX lobe at the registry's smallest width peaks far below the limit
    from brdf_fit import registry

    m = registry.get("ggx").build(alpha=1e-4, f0=1.0)
    w = np.array([0.0, 0.0, 1.0])
    assert float(np.max(m.eval(w, w))) < 1e-6 * MAX_VALUE


def test_a_huge_value_is_refused_on_read(tmp_path):
    with pytest.raises(DataError, match="huge.csv.*exceeds"):
        read(_with_value(tmp_path, "1e300"))
    d = read(_with_value(tmp_path, "1e14"))  # large but below the limit: accepted
    assert d.value.max() == 1e14


def test_the_cli_refuses_it_in_one_line(tmp_path, capsys):
    assert main(["fit", str(_with_value(tmp_path, "1e300")), "--model", "ggx"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exceeds" in err[0]


def test_validate_names_the_sample():
    wi = np.tile([0.0, 0.0, 1.0], (3, 1))
    with pytest.raises(DataError, match="sample 1"):
        GonioData(wi, wi, np.array([1.0, -2e15, 1.0])).validate(allow_negative_sigmas=1e30)
