"""The Rusinkiewicz image slice of MERL data (brdf_fit.plot.rusinkiewicz_slice, and the third
picture of ``brdf-fit plot --data FILE.binary``): the slice's directions are the MERL bin
centres themselves (against :func:`brdf_fit.io.merl.merl_bin_centres`, which makes every bin),
the data image is the table's own slice, the model that wrote the file has a log ratio of
rounding only, and a model that misses (Beckmann against GGX data) does not."""

import numpy as np
import pytest

from brdf_fit import registry
from brdf_fit.cli import main
from brdf_fit.io.merl import (
    MERL_DIMS,
    merl_bin_centres,
    merl_slice_centres,
    read_merl_table,
    write_merl,
)
from brdf_fit.plot import rusinkiewicz_slices


def test_slice_centres_are_the_bin_centres():
    wi_all, wo_all = merl_bin_centres()
    for i_pd in (0, 90, 179):
        wi, wo, _, _ = merl_slice_centres(i_pd)
        ith, itd = np.meshgrid(np.arange(90), np.arange(90), indexing="ij")
        flat = (ith * MERL_DIMS[1] + itd) * MERL_DIMS[2] + i_pd
        np.testing.assert_allclose(wi, wi_all[flat], rtol=0, atol=1e-15)
        np.testing.assert_allclose(wo, wo_all[flat], rtol=0, atol=1e-15)


TRUTH = {"alpha": 0.2, "f0": np.array([0.9, 0.6, 0.3])}


@pytest.fixture(scope="module")
def ggx_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("merl") / "ggx.binary"
    write_merl(path, registry.get("ggx").build(**TRUTH))
    return path


def test_slice_of_data_and_models(ggx_file):
    truth = registry.get("ggx").build(**TRUTH)
    table = read_merl_table(ggx_file)
    other = registry.get("beckmann").build(alpha=0.2, f0=np.array([0.9, 0.6, 0.3]))
    th, td, data, rows = rusinkiewicz_slices(table, [("ggx", truth), ("beckmann", other)])
    np.testing.assert_allclose(th[[0, -1]], [90 * (0.5 / 90) ** 2, 90 * (89.5 / 90) ** 2])
    np.testing.assert_allclose(td[[0, -1]], [0.5, 89.5])
    want = table[1, :, :, 90]
    np.testing.assert_array_equal(np.isnan(data), want < 0)
    np.testing.assert_array_equal(data[want >= 0], want[want >= 0])
    (_, m_truth, r_truth), (_, _, r_other) = rows
    ok = np.isfinite(r_truth)
    assert ok.sum() > 0.9 * np.sum(want > 0)
    assert np.abs(r_truth[ok]).max() < 1e-12  # the file stores f / scale in float64
    assert np.nanmax(np.abs(r_other)) > 0.1


@pytest.mark.slow
def test_plot_command_draws_the_slice(ggx_file, tmp_path, capsys):
    """The third picture of a MERL file (the first two draw all 1.1 million samples: slow)."""
    out = tmp_path / "p.png"
    assert main(["plot", "ggx", "--data", str(ggx_file), "-o", str(out)]) == 0
    assert (tmp_path / "p_slice.png").stat().st_size > 10_000
    assert "p_slice.png" in capsys.readouterr().out
