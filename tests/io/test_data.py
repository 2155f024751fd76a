"""GonioData: canonical form, validation messages that name the sample and the problem."""

import numpy as np
import pytest

from brdf_fit.data import DataError, GonioData, channel_wavelengths, wavelength_channels


def make(**kw):
    base = dict(theta_i=[30.0, 45.0], phi_i=[0.0, 10.0], theta_o=[30.0, 60.0],
                phi_o=[180.0, 190.0], value=[[0.1, 0.2, 0.3], [0.2, 0.3, 0.4]],
                channels=("R", "G", "B"))
    base.update(kw)
    return GonioData.from_angles_deg(**base)


def test_roundtrip_angles_and_shapes():
    d = make().validate()
    assert d.n == 2 and d.n_channels == 3 and len(d) == 2
    a = d.angles_deg()
    np.testing.assert_allclose(a["theta_o"], [30.0, 60.0])
    np.testing.assert_allclose(a["phi_o"], [180.0, 190.0])
    np.testing.assert_array_equal(d.weight, 1.0)
    one = GonioData.from_angles_deg([10.0], [0.0], [20.0], [180.0], [0.5])
    assert one.value.shape == (1, 1) and one.channels == ("Y",)


@pytest.mark.parametrize("kw,match", [
    ({"theta_o": [30.0, 95.0]}, r"sample 1: wo is at or below the horizon \(theta = 95 deg\)"),
    ({"value": [[0.1, np.nan, 0.3], [0.2, 0.3, 0.4]]}, "sample 0: value is not finite"),
    ({"value": [[0.1, 0.2, 0.3], [0.2, -0.3, 0.4]]}, "sample 1: value .* is negative"),
])
def test_validation_names_sample_and_problem(kw, match):
    with pytest.raises(DataError, match=match):
        make(**kw).validate()


def test_masked_samples_below_horizon_are_allowed():
    d = make(theta_o=[30.0, 95.0], weight=[[1, 1, 1], [0, 0, 0]])
    d.validate()
    assert d.subset(d.weight[:, 0] > 0).n == 1


def test_negative_within_noise_is_accepted_beyond_is_not():
    d = make(value=[[0.1, 0.2, 0.3], [0.2, -0.01, 0.4]], sigma=0.01)
    d.validate()  # one sigma below zero: noise
    with pytest.raises(DataError, match="more than 5 sigma below 0"):
        make(value=[[0.1, 0.2, 0.3], [0.2, -0.1, 0.4]], sigma=0.01).validate()


def test_shape_errors():
    with pytest.raises(DataError, match="channel name"):
        make(channels=("R", "G"))
    with pytest.raises(DataError, match="shape"):
        GonioData(wi=np.zeros((3, 3)), wo=np.zeros((2, 3)), value=np.zeros((2, 1)))
    d = GonioData(wi=[[0.0, 0.0, 2.0]], wo=[[0.0, 0.0, 1.0]], value=[0.1])
    with pytest.raises(DataError, match="wi is not a unit vector"):
        d.validate()


def test_spectral_channel_names():
    names = wavelength_channels([400, 550.5])
    assert names == ("400nm", "550.5nm")
    np.testing.assert_allclose(channel_wavelengths(names), [400, 550.5])
    assert channel_wavelengths(("R", "G", "B")) is None


def test_one_dimensional_sigma_and_weight_are_per_sample():
    """GonioData(value (N,), sigma (N,)) used to fail with a NumPy broadcast error (issue 16);
    a 1-D sigma or weight is per sample, and a shape that fits nothing is a DataError."""
    import numpy as np
    import pytest

    from brdf_fit.data import DataError, GonioData

    wi = np.tile([0.0, 0.0, 1.0], (5, 1))
    d = GonioData(wi=wi, wo=wi, value=np.ones(5), sigma=np.arange(1, 6) / 10, weight=np.ones(5))
    assert d.value.shape == d.sigma.shape == d.weight.shape == (5, 1)
    np.testing.assert_array_equal(d.sigma[:, 0], np.arange(1, 6) / 10)
    rgb = GonioData(wi=wi, wo=wi, value=np.ones((5, 3)), sigma=np.arange(1, 6) / 10,
                    channels=("R", "G", "B"))
    np.testing.assert_array_equal(rgb.sigma, np.repeat(np.arange(1, 6)[:, None] / 10, 3, 1))
    with pytest.raises(DataError, match=r"sigma has shape \(4,\)"):
        GonioData(wi=wi, wo=wi, value=np.ones((5, 3)), sigma=np.ones(4),
                  channels=("R", "G", "B"))
