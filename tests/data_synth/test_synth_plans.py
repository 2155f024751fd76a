"""Measurement plans: geometry (unit, above the horizon, max zenith), the four-axis mechanical
limits, counts, determinism, the half/difference identities and the MERL grid."""

import math

import numpy as np
import pytest

from data_synth.plans import (
    PLANS,
    PlanError,
    four_axis,
    half_diff_to_io,
    hemisphere_grid,
    in_plane,
    io_to_half_diff,
    make_plan,
    merl_grid,
    random_sparse,
    unit_from_angles,
)


def _zenith_deg(w):
    return np.degrees(np.arccos(np.clip(w[:, 2], -1.0, 1.0)))


def _check_geometry(plan, max_zenith=90.0):
    for w in plan:
        assert w.dtype == np.float64 and w.ndim == 2 and w.shape[1] == 3
        np.testing.assert_allclose(np.linalg.norm(w, axis=-1), 1.0, atol=1e-14)
        assert (w[:, 2] > 0).all()
        assert (_zenith_deg(w) <= max_zenith + 1e-9).all()


ALL = [
    ("in_plane", {}),
    ("hemisphere_grid", {"n_theta_i": 4, "n_theta_o": 5, "n_phi": 8, "max_zenith_deg": 80}),
    ("four_axis", {"max_zenith_deg": 70, "min_separation_deg": 10}),
    ("random_sparse", {"n": 300, "seed": 3, "max_zenith_deg": 60}),
    ("random_sparse", {"n": 300, "seed": 3, "distribution": "cosine"}),
    ("merl_grid", {"subsample": 9}),
]


@pytest.mark.parametrize("name,args", ALL)
def test_every_plan_is_unit_above_horizon_and_reproducible(name, args):
    plan = make_plan(name, args)
    _check_geometry(plan, args.get("max_zenith_deg", 90.0))
    again = make_plan(name, args)
    np.testing.assert_array_equal(plan.wi, again.wi)
    np.testing.assert_array_equal(plan.wo, again.wo)
    # info names the plan and rebuilds it
    assert plan.info["name"] == name
    rebuilt = make_plan(plan.info["name"], plan.info["args"])
    np.testing.assert_array_equal(rebuilt.wi, plan.wi)
    assert len(plan) == plan.n == plan.wi.shape[0] == plan.wo.shape[0]


def test_unit_from_angles():
    np.testing.assert_allclose(unit_from_angles(90.0, 90.0), [0, 1, 0], atol=2e-16)
    np.testing.assert_allclose(unit_from_angles([60.0], [180.0]),
                               [[-math.sqrt(3) / 2, 0, 0.5]], atol=2e-16)


def test_in_plane_geometry_and_signed_angles():
    ti, to = [0.0, 30.0, 60.0], [-45.0, -30.0, 0.0, 30.0, 80.0]
    p = in_plane(ti, to, phi_i_deg=20.0)
    assert p.n == len(ti) * len(to)
    # every pair lies in the plane of incidence: (wi x wo) . n_plane = 0, plane normal at 20 deg
    n_plane = np.array([-math.sin(math.radians(20)), math.cos(math.radians(20)), 0.0])
    np.testing.assert_allclose(p.wi @ n_plane, 0.0, atol=1e-15)
    np.testing.assert_allclose(p.wo @ n_plane, 0.0, atol=1e-15)
    TI, TO = (g.ravel() for g in np.meshgrid(ti, to, indexing="ij"))
    np.testing.assert_allclose(_zenith_deg(p.wi), TI, atol=1e-6)
    np.testing.assert_allclose(_zenith_deg(p.wo), np.abs(TO), atol=1e-6)
    # theta_o = +theta_i is the mirror direction; theta_o = -theta_i is retro-reflection
    spec = (TO == TI) & (TI > 0)
    np.testing.assert_allclose(p.wo[spec], p.wi[spec] * [-1, -1, 1], atol=1e-15)
    retro = (TO == -TI) & (TI > 0)
    assert retro.sum() == 1
    np.testing.assert_allclose(p.wo[retro], p.wi[retro], atol=1e-15)
    with pytest.raises(PlanError, match=r"theta_o_deg must be > -90"):
        in_plane([10.0], [-90.0])
    with pytest.raises(PlanError, match=r"theta_i_deg must lie in \[0, 90\) degrees"):
        in_plane([90.0], [10.0])


def test_hemisphere_grid_count_and_pole_once():
    n_ti, n_to, n_phi, n_phi_i = 4, 5, 8, 3
    p = hemisphere_grid(n_ti, n_to, n_phi, max_zenith_deg=75.0, n_phi_i=n_phi_i)
    s_i, s_o = 1 + (n_ti - 1) * n_phi_i, 1 + (n_to - 1) * n_phi
    assert p.n == s_i * s_o
    # every pair is distinct (the pole appears once per side, not n_phi times)
    pairs = np.round(np.concatenate([p.wi, p.wo], 1), 12)
    assert np.unique(pairs, axis=0).shape[0] == p.n
    np.testing.assert_allclose(np.unique(np.round(_zenith_deg(p.wo), 9)),
                               np.linspace(0, 75, n_to), atol=1e-6)
    assert _zenith_deg(p.wo).max() == pytest.approx(75.0, abs=1e-9)
    with pytest.raises(PlanError, match=r"max_zenith_deg must lie in \(0, 90\)"):
        hemisphere_grid(max_zenith_deg=90.0)
    with pytest.raises(PlanError, match="n_phi must be a positive integer"):
        hemisphere_grid(n_phi=0)


def test_four_axis_mechanical_limits():
    args = dict(theta_i_deg=range(0, 90, 5), theta_o_deg=range(0, 90, 5),
                phi_o_deg=range(0, 360, 10), max_zenith_deg=72.0, min_separation_deg=8.0,
                phi_i_deg=(0.0, 45.0))
    p = four_axis(**args)
    # nothing beyond the zenith limit, nothing inside the blocking cone around retro-reflection
    assert _zenith_deg(p.wi).max() <= 72.0 + 1e-9 and _zenith_deg(p.wo).max() <= 72.0 + 1e-9
    sep = np.degrees(np.arccos(np.clip(np.sum(p.wi * p.wo, -1), -1, 1)))
    assert sep.min() >= 8.0
    # the limits drop exactly what they should: recount by brute force
    TI, PI, TO, PO = (g.ravel() for g in np.meshgrid(
        np.arange(0, 90, 5.0), [0.0, 45.0], np.arange(0, 90, 5.0), np.arange(0, 360, 10.0),
        indexing="ij"))
    wi, wo = unit_from_angles(TI, PI), unit_from_angles(TO, PO)
    zen = (TI > 72) | (TO > 72)
    blocked = ~zen & (np.degrees(np.arccos(np.clip(np.sum(wi * wo, -1), -1, 1))) < 8.0)
    assert p.info["n_grid"] == TI.size
    assert p.info["n_dropped_zenith"] == zen.sum()
    assert p.info["n_dropped_blocked"] == blocked.sum() > 0
    assert p.n == TI.size - zen.sum() - blocked.sum()
    np.testing.assert_array_equal(p.wi, wi[~zen & ~blocked])
    # the blocked region is near retro-reflection, never the specular direction
    spec = four_axis([40.0], [40.0], [180.0], min_separation_deg=8.0)
    assert spec.n == 1
    # at zenith 40 deg an azimuth offset dphi separates the arms by ~ dphi sin(40 deg):
    # 0 (retro-reflection) and 10 deg (6.4 deg apart) are blocked, 20 deg (12.8 apart) is not
    retro = four_axis([40.0], [40.0], [0.0, 10.0, 20.0], min_separation_deg=8.0)
    assert retro.n == 1 and retro.info["n_dropped_blocked"] == 2
    np.testing.assert_allclose(retro.wo, unit_from_angles([40.0], [20.0]))
    with pytest.raises(PlanError, match=r"min_separation_deg must lie in \[0, 180\)"):
        four_axis(min_separation_deg=-1.0)


def test_random_sparse_distributions_and_seed():
    n = 4000
    u = random_sparse(n, seed=11, max_zenith_deg=60.0)
    c = random_sparse(n, seed=11, max_zenith_deg=60.0, distribution="cosine")
    assert u.n == c.n == n
    cmax = 0.5
    # uniform in solid angle: cos(theta) ~ U(cos max, 1), mean (1 + cmax)/2, sd (1-cmax)/sqrt(12)
    for w in (u.wi, u.wo):
        z = w[:, 2]
        assert z.min() >= cmax
        se = (1 - cmax) / math.sqrt(12 * n)
        assert abs(z.mean() - (1 + cmax) / 2) < 4 * se
        # azimuth uniform: the mean resultant of phi is ~ 0
        assert abs(np.mean(w[:, 0] + 1j * w[:, 1]) / np.mean(np.hypot(w[:, 0], w[:, 1]))) \
            < 4 / math.sqrt(n)
    # cosine-weighted: sin^2(theta) ~ U(0, sin^2 max)
    s2 = 1 - c.wi[:, 2] ** 2
    smax2 = 1 - cmax**2
    assert abs(s2.mean() - smax2 / 2) < 4 * smax2 / math.sqrt(12 * n)
    # wi and wo are independent draws, not copies
    assert abs(np.corrcoef(u.wi[:, 2], u.wo[:, 2])[0, 1]) < 4 / math.sqrt(n)
    # the seed decides everything
    assert not np.array_equal(random_sparse(10, seed=1).wi, random_sparse(10, seed=2).wi)
    with pytest.raises(PlanError, match="distribution must be 'uniform' or 'cosine'"):
        random_sparse(10, distribution="gaussian")


# ----------------------------------------------------------------------------- half / diff


def _random_half_diff(n=2000, seed=0):
    rng = np.random.default_rng(seed)
    return (rng.uniform(0.01, 1.5, n), rng.uniform(-3.1, 3.1, n), rng.uniform(0.01, 1.5, n),
            rng.uniform(-3.1, 3.1, n))


def test_half_diff_roundtrip_identity():
    th, ph, td, pd = _random_half_diff()
    wi, wo = half_diff_to_io(th, ph, td, pd)
    np.testing.assert_allclose(np.linalg.norm(wi, axis=-1), 1.0, atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(wo, axis=-1), 1.0, atol=1e-14)
    back = io_to_half_diff(wi, wo)
    for got, want in zip(back, (th, ph, td, pd), strict=True):
        np.testing.assert_allclose(got, want, atol=1e-12)
    # and the other way round, from random direction pairs
    rs = random_sparse(2000, seed=5, max_zenith_deg=89.0)
    wi2, wo2 = half_diff_to_io(*io_to_half_diff(rs.wi, rs.wo))
    np.testing.assert_allclose(wi2, rs.wi, atol=1e-12)
    np.testing.assert_allclose(wo2, rs.wo, atol=1e-12)


def test_half_diff_geometry():
    th, ph, td, pd = _random_half_diff(seed=1)
    wi, wo = half_diff_to_io(th, ph, td, pd)
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    # h is the (theta_h, phi_h) direction and theta_d the angle between wi and h
    np.testing.assert_allclose(h, np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph),
                                            np.cos(th)], -1), atol=1e-13)
    np.testing.assert_allclose(np.sum(wi * h, -1), np.cos(td), atol=1e-13)
    # reciprocity: swapping wi and wo keeps theta_h, phi_h, theta_d and shifts phi_d by pi
    th2, ph2, td2, pd2 = io_to_half_diff(wo, wi)
    np.testing.assert_allclose(th2, th, atol=1e-12)
    np.testing.assert_allclose(ph2, ph, atol=1e-12)
    np.testing.assert_allclose(td2, td, atol=1e-12)
    np.testing.assert_allclose(np.cos(pd2 - pd), -1.0, atol=1e-12)
    # normal half vector: wi is d itself
    wi0, wo0 = half_diff_to_io(0.0, 0.0, 0.4, 0.3)
    np.testing.assert_allclose(wi0, [math.sin(0.4) * math.cos(0.3), math.sin(0.4) *
                                     math.sin(0.3), math.cos(0.4)], atol=1e-16)
    np.testing.assert_allclose(wo0, wi0 * np.array([-1, -1, 1]), atol=1e-16)


def test_merl_grid_positions_and_count():
    p = merl_grid(subsample=(5, 7, 11))
    i, j, k = p.extra["index"].T
    th, ph, td, pd = io_to_half_diff(p.wi, p.wo)
    np.testing.assert_allclose(th, ((i + 0.5) / 90) ** 2 * math.pi / 2, atol=1e-12)
    np.testing.assert_allclose(td, (j + 0.5) / 90 * math.pi / 2, atol=1e-12)
    np.testing.assert_allclose(np.mod(pd, math.pi), (k + 0.5) / 180 * math.pi, atol=1e-12)
    assert set(np.unique(i)) <= set(range(0, 90, 5)) and set(np.unique(k)) <= set(range(0, 180,
                                                                                        11))
    assert p.info["n_grid"] == 18 * 13 * 17
    assert p.info["n_kept"] == p.n < p.info["n_grid"]
    # the kept set is exactly {both z > 0}: tan th tan td |cos pd| < 1
    I, J, K = (g.ravel() for g in np.meshgrid(range(0, 90, 5), range(0, 90, 7),
                                              range(0, 180, 11), indexing="ij"))
    t = np.tan(((I + 0.5) / 90) ** 2 * math.pi / 2) * np.tan((J + 0.5) / 90 * math.pi / 2)
    assert p.n == int((t * np.abs(np.cos((K + 0.5) / 180 * math.pi)) < 1).sum())
    with pytest.raises(PlanError, match="subsample must be a positive integer"):
        merl_grid(subsample=1.5)


def test_make_plan_errors_name_choices():
    with pytest.raises(PlanError, match=r"unknown plan 'spiral'; valid plans: in_plane"):
        make_plan("spiral")
    with pytest.raises(PlanError, match=r"plan 'four_axis': unknown argument\(s\) 'zenith'; "
                                        r"valid arguments: theta_i_deg"):
        make_plan("four-axis", {"zenith": 3})
    with pytest.raises(PlanError, match=r"n must be a positive integer, got 'many'"):
        make_plan("random_sparse", {"n": "many"})
    with pytest.raises(PlanError, match=r"plan 'four_axis': invalid argument value"):
        make_plan("four_axis", {"theta_i_deg": ["ten"]})
    assert set(PLANS) == {"in_plane", "hemisphere_grid", "four_axis", "random_sparse",
                          "merl_grid"}


def test_plans_past_the_memory_limit_are_refused_before_allocation(tmp_path):
    """Plans whose sample count (from their arguments alone) would pass the memory limit are a
    one-line PlanError (issue 45: a hemisphere grid of 10^5 per axis grew to 23 GB and was
    killed; random_sparse of 10^9 and merl_grid of 10^5 per axis ended in MemoryError), and
    through `brdf-fit synth` a one-line error with exit status 2, the process at its imports'
    memory; `lut albedo` on 10^6 x 10^6 nodes likewise."""
    import json
    import subprocess
    import sys

    from _helpers import PEAK_RSS_CODE, peak_kib

    from data_synth.plans import PlanError, make_plan

    for name, args in (("hemisphere_grid", {"n_theta_i": 10**5, "n_theta_o": 10**5,
                                            "n_phi": 10**5}),
                       ("random_sparse", {"n": 10**9}),
                       ("merl_grid", {"n_theta_h": 10**5, "n_theta_d": 10**5, "n_phi_d": 10**5}),
                       ("four_axis", {"theta_i_deg": list(np.linspace(0, 80, 2000)),
                                      "theta_o_deg": list(np.linspace(0, 80, 2000)),
                                      "phi_o_deg": list(np.linspace(0, 359, 2000))})):
        with pytest.raises(PlanError, match=rf"plan {name}: [0-9,]+ samples .* over the memory "
                                            "limit"):
            make_plan(name, args)
    recipe = tmp_path / "bomb.json"
    recipe.write_text(json.dumps({"model": "lambert", "params": {"rho": 0.5}, "seed": 1, "plan": {
        "name": "hemisphere_grid", "args": {"n_theta_i": 10**5, "n_theta_o": 10**5,
                                            "n_phi": 10**5}}}))
    code = PEAK_RSS_CODE + ("from brdf_fit.cli import main\n"
                            "status = main(_s.argv[1:])\n"
                            "_peak()\n"
                            "_s.exit(status)\n")
    for argv in (["synth", str(recipe), "-o", str(tmp_path / "x.npz")],
                 ["lut", "albedo", "ggx", "--axis", "mu=1000000", "--axis", "alpha=1000000",
                  "-o", str(tmp_path / "t.npz")]):
        out = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True,
                             text=True, timeout=300)
        assert out.returncode == 2, out.stderr[-1500:]
        errors = [ln for ln in out.stderr.splitlines() if ln.startswith("brdf-fit: error:")]
        assert len(errors) == 1 and "over the memory limit" in errors[0], out.stderr
        assert "Traceback" not in out.stderr
        assert peak_kib(out.stderr) < 500 * 1024, out.stderr
