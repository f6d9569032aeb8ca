"""Rerun recordings: the posterior density of eq. (26) against brute force, recordings read
back (`rerun.chunk.RrdReader`) against the Result CSV of the same run, every documented
entity path, the points per logged step, friction curves and Gaussian posteriors from a
small fake estimator, replay, and streaming to a local gRPC receiver (--connect)."""

from __future__ import annotations

import math
import os
import re
import signal
import socket
import subprocess
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from tirefilter.cli import main
from tirefilter.io.results import read_results
from tirefilter.cosim.run import run_scenario
from tirefilter.errors import ConfigError
from tirefilter.estimators.base import Estimate, FrictionCurve, Posterior
from tirefilter.replay import write_log
from tirefilter.scenarios import DATA_DIR, load_scenario
from tirefilter.vehicle.tires import pure_lateral_friction
from tirefilter.viz.density import (ComponentCache, gaussian_marginals, mixture_pdf, niw_mean_marginals, stiffness_grid,
                                    stiffness_mixture, weighted_kde)
from tirefilter.viz.options import RecordingOptions

REPO = Path(__file__).resolve().parents[1]
N, K, DURATION = 100, 25, 12.0  # particles, --log-every, seconds of paper-sim
VEHICLE = DATA_DIR / "vehicles" / "midsize-suv.toml"


# ---- eq. (26): the density against brute force -------------------------------------------
def _niw(seed=0, n=3, N=200):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(N, n, n))
    Lam = (A @ np.swapaxes(A, 1, 2) + n * np.eye(n)) * 4e6
    return dict(log_weights=rng.normal(size=N) * 2, gamma=rng.uniform(0.01, 0.2, N), mu=rng.normal(0, 3000, (N, n)),
                Lam=Lam, nu=rng.uniform(n + 2.5, 60, N), C_nominal=np.array([2e5, 1e5, 1.1e5]),
                params=("Cx", "Cf_y", "Cr_y"))


def test_eq26_density_equals_the_scipy_student_t_mixture_and_integrates_to_one():
    s = _niw()
    mix = niw_mean_marginals(**s)
    w = np.exp(s["log_weights"] - s["log_weights"].max())
    w /= w.sum()
    n = 3
    df = s["nu"] - n + 1
    for j, p in enumerate(s["params"]):
        grid = stiffness_grid(s["C_nominal"][j], 0.5, 1.5, 4001)
        got = mix.pdf(p, grid)
        scale = np.sqrt(s["gamma"] * s["Lam"][:, j, j] / df)
        brute = sum(w[i] * stats.t.pdf(grid, df[i], loc=s["C_nominal"][j] + s["mu"][i, j], scale=scale[i])
                    for i in range(len(w)))
        np.testing.assert_allclose(got, brute, rtol=1e-9, atol=1e-12 * brute.max())
        # on a grid that resolves every component and holds all but a negligible tail
        assert abs(np.trapezoid(got, grid) - 1.0) < 1e-6
        # the mixture's variance: per particle gamma Lam_jj / (nu - n - 1), plus the spread of the means
        m = w @ (s["C_nominal"][j] + s["mu"][:, j])
        spread = w @ (s["mu"][:, j] + s["C_nominal"][j] - m) ** 2
        var = w @ (s["gamma"] * s["Lam"][:, j, j] / (s["nu"] - n - 1)) + spread
        assert abs(np.trapezoid(got * grid, grid) - m) < 1e-6 * m
        # heavy tails: the grid's second moment converges slowly, 1e-3 is what [0.5, 1.5] x C holds
        assert np.trapezoid(got * (grid - m) ** 2, grid) == pytest.approx(var, rel=2e-3)


def test_a_calibrated_std_widens_the_density_about_its_mean_by_its_factor():
    """The MPF's posterior carries `std_factor` when its lateral `*_std` is calibrated
    (derivations, "Batch-means sandwich"): the density drawn is eq. (26) stretched about its mean, whose mean
    stays and whose std (integrated on a grid) is the factor times eq. (26)'s."""
    s = _niw(seed=3)
    plain = niw_mean_marginals(**s)
    f = np.array([1.0, 1.7, 2.3])
    post = Posterior(np.zeros((len(s["gamma"]), 3)), s["log_weights"],
                     {k: s[k] for k in ("gamma", "mu", "Lam", "nu", "C_nominal", "params")} | {"std_factor": f})
    wide = stiffness_mixture(post)
    for j, p in enumerate(s["params"]):
        grid = s["C_nominal"][j] * np.linspace(1.0 - 0.4 * f[j], 1.0 + 0.4 * f[j], 40001)
        moments = []
        for mix in (plain, wide):
            d = mix.pdf(p, grid)
            m = np.trapezoid(d * grid, grid)
            moments.append((m, math.sqrt(np.trapezoid(d * (grid - m) ** 2, grid))))
        (m0, s0), (m1, s1) = moments
        assert m1 == pytest.approx(m0, rel=1e-6)
        assert s1 == pytest.approx(f[j] * s0, rel=2e-3)
    with pytest.raises(ValueError, match="std_factor"):
        stiffness_mixture(Posterior(post.particles, post.log_weights, post.stats | {"std_factor": [1.0, 0.5, 1.0]}))


def test_niw_marginal_of_the_mean_matches_monte_carlo():
    """The Student-t marginal of one particle's mean, against draws of
    Sigma ~ iW(nu, Lam), mu | Sigma ~ N(mu_hat, gamma Sigma)."""
    rng = np.random.default_rng(1)
    n, nu, gamma = 3, 9.0, 0.3
    Lam = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, -0.4], [0.5, -0.4, 2.0]])
    mu_hat = np.array([1.0, -2.0, 0.5])
    Sig = stats.invwishart(df=nu, scale=Lam).rvs(size=40000, random_state=rng)
    mu = mu_hat + np.einsum("kij,kj->ki", np.linalg.cholesky(gamma * Sig), rng.standard_normal((40000, n)))
    mix = niw_mean_marginals(np.zeros(1), [gamma], mu_hat[None] * 0, Lam[None], [nu], mu_hat, ("a", "b", "c"))
    for j, p in enumerate(mix.params):
        res = stats.kstest(mu[:, j], lambda x: stats.t.cdf(x, mix.df[0], loc=mix.loc[0, j], scale=mix.scale[0, j]))
        assert res.pvalue > 1e-3, (p, res)


def test_gaussian_and_kde_mixtures_against_direct_sums():
    grid = np.linspace(-10, 10, 2001)
    g = gaussian_marginals([0.0], [[1.0, 2.0]], [[0.5, 2.0]], ("a", "b"))
    np.testing.assert_allclose(g.pdf("b", grid), stats.norm.pdf(grid, 2.0, 2.0), rtol=1e-12, atol=1e-300)
    rng = np.random.default_rng(2)
    x, lw = rng.normal(size=(300, 1)), rng.normal(size=300)
    kde = weighted_kde(lw, x, ("a",))
    w = np.exp(lw - lw.max())
    w /= w.sum()
    h = kde.scale[0, 0]
    brute = (w[:, None] * stats.norm.pdf(grid, x, h)).sum(0)
    # points where every component is below EPS = 1e-12 of its peak are left at 0 (viz.density)
    np.testing.assert_allclose(kde.pdf("a", grid), brute, rtol=1e-9, atol=1e-12 * brute.max())
    assert kde.kind == "kde" and abs(np.trapezoid(kde.pdf("a", grid), grid) - 1) < 1e-6
    assert mixture_pdf(grid, [1.0], [np.nan], [1.0], [5.0]).max() == 0  # nothing finite: zero, no error


def test_cached_and_deduplicated_evaluation_equals_the_plain_one():
    """A sequence as a filter produces it: resampled copies (duplicates), frozen statistics
    with new weights (cache hits), a narrower window inside the cached one, then new
    components (misses) with a wider window."""
    rng = np.random.default_rng(3)
    grid = np.linspace(0, 3.6e5, 1601)
    M = 300
    loc, scale, df = rng.normal(1e5, 1e4, M), rng.uniform(2e3, 8e3, M), np.full(M, 40.0)
    cache = ComponentCache()
    idx = rng.integers(0, M, M)
    order = np.argsort(loc)[M // 2 - 5:M // 2 + 5]  # ten central components: a narrower window
    steps = [(rng.random(M), loc, scale, df), (rng.random(M), loc[idx], scale[idx], df[idx]),
             (rng.random(M), loc[idx], scale[idx], df[idx]), (rng.random(10), loc[order], scale[order], df[order]),
             (rng.random(M), rng.normal(2e5, 3e4, M), rng.uniform(1e3, 2e4, M), np.full(M, 6.0))]
    for w, l, s_, d in steps:
        plain = mixture_pdf(grid, w, l, s_, d)
        # the cache may evaluate a wider window than needed: points below EPS of every peak
        np.testing.assert_allclose(mixture_pdf(grid, w, l, s_, d, cache), plain, rtol=1e-12,
                                   atol=1e-12 * plain.max())
        brute = sum(wi * stats.t.pdf(grid, di, li, si) for wi, li, si, di in zip(w, l, s_, d))
        np.testing.assert_allclose(plain, brute, rtol=1e-9, atol=1e-12 * brute.max())
    kept = len(np.unique(idx))  # distinct components after 'resampling'
    central_kept = int(np.isin(order, idx).sum())  # the cache holds the previous call's components only
    assert cache.hits == 2 * kept + central_kept and cache.misses == M + (10 - central_kept) + M
    # after the wide last step, a narrow posterior gets a narrow window again (not the full grid)
    mixture_pdf(grid, np.ones(5), np.full(5, 1e5), np.full(5, 500.0), np.full(5, 100.0), cache)
    assert cache.hi - cache.lo < 100


def test_stiffness_mixture_picks_what_the_posterior_supports():
    s = _niw(N=5)
    niw = Posterior(np.zeros((5, 3)), s["log_weights"], {k: s[k] for k in ("gamma", "mu", "Lam", "nu", "C_nominal",
                                                                           "params")})
    assert stiffness_mixture(niw).kind == "eq26-student-t"
    augmented = Posterior(np.zeros((5, 3)), np.zeros(5), {"stiffness": np.ones((5, 2)), "params": ("Cf_y", "Cr_y")})
    assert stiffness_mixture(augmented).kind == "kde"
    est = Estimate(active=True, vx=10, vy=0, yaw_rate=0, Cf_y=1e5, Cr_y=1.2e5, Cf_y_std=1e3, Cr_y_std=2e3)
    kf = Posterior(np.zeros((1, 2)), np.zeros(1), {"cov": np.eye(2)[None]})
    gauss = stiffness_mixture(kf, est)  # one 'particle': a Gaussian filter, its estimate and std
    assert gauss.kind == "gaussian" and gauss.params == ("Cf_y", "Cr_y") and gauss.scale[0, 1] == 2e3
    fixed = Estimate(active=True, vx=10, vy=0, yaw_rate=0, Cf_y=1e5, Cr_y=1.2e5, Cf_y_std=0.0, Cr_y_std=0.0)
    assert stiffness_mixture(kf, fixed) is None  # fixed stiffness (kf): nothing to draw
    augpf = Posterior(np.zeros((5, 7)), np.zeros(5), {"mu": np.ones((5, 2)), "var": np.ones((5, 2)),
                                                      "C_nominal": np.array([1e5, 1e5]), "params": ("Cf_y", "Cr_y")})
    kde = stiffness_mixture(augpf)
    assert kde.kind == "kde" and np.all(kde.loc == 1e5 + 1)
    assert stiffness_mixture(None, None) is None


# ---- recordings read back --------------------------------------------------------------------
def read_recording(path) -> dict[str, list[dict]]:
    """entity path -> rows, each {"t": s or None (static), component: value}."""
    from rerun.chunk import RrdReader

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a stream received over gRPC has no footer: "legacy format"
        reader = RrdReader(path)
    try:
        chunks = reader.store().stream()
    except RuntimeError:  # no footer: read it whole
        chunks = reader.stream().collect().stream()
    out: dict[str, list[dict]] = {}
    for chunk in chunks:
        batch = chunk.to_record_batch()
        names = batch.schema.names
        cols = {n: batch.column(n).to_pylist() for n in names if ":" in n and not n.startswith("rerun.")}
        t = batch.column(names.index("sim_time")).cast("int64").to_pylist() if "sim_time" in names else None
        for i in range(batch.num_rows):
            row = {"t": None if t is None else t[i] * 1e-9}
            row.update({n: v[i] for n, v in cols.items() if v[i] is not None})
            out.setdefault(chunk.entity_path, []).append(row)
    for rows in out.values():
        rows.sort(key=lambda r: -1.0 if r["t"] is None else r["t"])
    return out


def series(rec, entity):
    rows = [r for r in rec[entity] if "Scalars:scalars" in r]
    return np.array([r["t"] for r in rows]), np.array([r["Scalars:scalars"][0] for r in rows])


def temporal(rec, entity, component):
    return [r for r in rec.get(entity, []) if r["t"] is not None and component in r]


def _short_scenario(tmp_path: Path, duration=DURATION) -> Path:
    text = (DATA_DIR / "paper-sim.toml").read_text()
    text = re.sub(r"(?m)^duration = 60\.0", f"duration = {duration}", text)
    text = re.sub(r'(?m)^name = "paper-sim"', 'name = "paper-sim-short"', text)
    text = re.sub(r"(?m)^excitation = .*$", f"excitation = [[0.0, {duration}]]", text)
    text = text.replace("times = [0.0, 30.0]\nvalues = [1.0, 0.5]", "times = [0.0]\nvalues = [1.0]")
    path = tmp_path / "short.toml"
    path.write_text(text)
    return path


def documented_paths(e: str, params, lateral: bool) -> list[str]:
    """The table of docs/rerun.md, for estimator `e` (kept in step with it by
    test_docs_list_every_documented_path)."""
    out = [f"/truth/{c}" for c in ("vx", "vy", "yaw_rate", "beta", "alpha_f", "alpha_r", "Cf_y", "Cr_y", "Cx",
                                   "Cf_y_mean", "Cr_y_mean", "Cx_mean", "b_ax", "b_ay", "b_yaw_rate", "delta")]
    out += [f"/sensors/{s}" for s in ("ax", "ay", "yaw_rate", "omega_f", "omega_r", "delta")]
    out += ["/vehicle/x", "/vehicle/y", "/vehicle/psi", "/vehicle/path", "/vehicle/trail", "/vehicle/body",
            "/vehicle/body/outline", "/vehicle/body/heading", "/vehicle/body/steer", "/vehicle/body/frame"]
    b = f"/estimator/{e}"
    out += [f"{b}/state/{s}" for s in ("vx", "vy", "yaw_rate", "beta")]
    out += [f"{b}/bias/{s}" for s in ("ay", "yaw_rate") + (() if lateral else ("ax",))]
    out += [f"{b}/ess", f"{b}/active", f"{b}/particles/stiffness", f"{b}/particles/state"]
    for p in params:
        out += [f"{b}/stiffness/{p}", f"{b}/stiffness/{p}_std", f"{b}/stiffness/{p}_sigma", f"{b}/density/{p}",
                f"{b}/density_history/{p}"]
        out += [f"{b}/stiffness/{p}/{w}_{s}" for w in ("posterior", "spread") for s in ("lower", "upper")]
    return out


@pytest.fixture(scope="module")
def cosim_recording(fmu_paths, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("viz")
    out, rrd = tmp / "run", tmp / "run.rrd"
    assert main(["run", "--scenario", str(_short_scenario(tmp)), "--particles", str(N), "--seed", "4", "--out",
                 str(out), "--rrd", str(rrd), "--log-every", str(K), "--quiet"]) == 0
    return read_results(out / "results.csv"), read_recording(rrd), rrd


def test_recorded_series_equal_the_result_csv(cosim_recording):
    from tirefilter.viz.paths import entity_path

    r, rec, _ = cosim_recording
    checked = 0
    for column, values in r.items():
        path = entity_path(column, "mpf")
        if path is None:
            continue
        keep = ~np.isnan(values)
        if not keep.any():
            assert path not in rec, path
            continue
        t, v = series(rec, path)
        np.testing.assert_allclose(t, r["t"][keep], rtol=0, atol=1e-9, err_msg=path)
        np.testing.assert_array_equal(v, values[keep], err_msg=path)
        checked += 1
    assert checked > 60
    t, lower = series(rec, "/estimator/mpf/stiffness/Cf_y/posterior_lower")
    np.testing.assert_allclose(lower, r["Cf_y"] - 2 * r["Cf_y_std"], rtol=1e-15)
    t, upper = series(rec, "/estimator/mpf/stiffness/Cr_y/spread_upper")
    np.testing.assert_allclose(upper, r["Cr_y"] + 2 * r["Cr_y_sigma"], rtol=1e-15)


def test_every_documented_path_exists_with_a_blueprint(cosim_recording):
    _, rec, rrd = cosim_recording
    missing = [p for p in documented_paths("mpf", ("Cf_y", "Cr_y", "Cx"), lateral=False) if p not in rec]
    assert not missing
    from rerun.chunk import RrdReader

    assert len(RrdReader(rrd).blueprints()) == 1


def test_docs_list_every_documented_path():
    readme = (REPO / "docs" / "rerun.md").read_text()
    section = readme[readme.index("### Rerun entity paths"):]
    section = section.split("\n## ")[0]
    for path in documented_paths("mpf", ("Cf_y",), False):
        named = path.replace("/mpf", "/<name>")
        forms = {named, re.sub(r"Cf_y|Cr_y|Cx", "<param>", named)}
        leaves = {f.rsplit("/", 1)[-1] for f in forms}
        assert any(f"`{f}`" in section for f in forms) or any(
            f"`{x}`" in section or f"{x}," in section or f"{x}>" in section for x in leaves), path
    for p in ("/estimator/<name>/friction/<axle>", "/truth/friction/<axle>", "/estimator/<name>/density/<param>"):
        assert p in section, p


def test_particles_and_densities_hold_the_expected_points_per_logged_step(cosim_recording):
    r, rec, _ = cosim_recording
    steps = len(r["t"])
    logged_t = r["t"][::K]
    for what in ("stiffness", "state"):
        rows = temporal(rec, f"/estimator/mpf/particles/{what}", "Points3D:positions")
        np.testing.assert_allclose([x["t"] for x in rows], logged_t, atol=1e-9)
        assert all(len(x["Points3D:positions"]) == N and len(x["Points3D:colors"]) == N for x in rows)
    assert len(logged_t) == (steps - 1) // K + 1
    # the stiffness cloud at the last logged step: its weighted... mean lies inside the points' range
    for p in ("Cf_y", "Cr_y", "Cx"):
        entity = f"/estimator/mpf/density/{p}"
        static = [x for x in rec[entity] if x["t"] is None]
        grid = np.asarray(static[0]["BarChart:abscissa"][0]["buffer"], float)
        assert len(grid) == RecordingOptions().density_points
        rows = temporal(rec, entity, "BarChart:values")
        np.testing.assert_allclose([x["t"] for x in rows], logged_t, atol=1e-9)
        i_csv = np.searchsorted(r["t"], logged_t - 1e-9)
        t_mass, exact = series(rec, f"{entity}/mass")
        np.testing.assert_allclose(t_mass, logged_t, atol=1e-9)
        compared = 0
        for x, i, inside in zip(rows, i_csv, exact):
            d = np.asarray(x["BarChart:values"][0]["buffer"], float)
            assert d.shape == grid.shape
            # eq. (26) on the grid holds the exact probability of the grid's range (from the
            # components' CDFs, logged beside it); float32 storage, grid spacing 0.225 % of C
            mass = np.trapezoid(d, grid)
            assert abs(mass - inside) < 1e-4, (p, x["t"], mass, inside)
            if inside < 1 - 1e-6:
                continue  # part of the posterior lies beyond the plotted range (heavy tails early on)
            # ... and its mean and std are the Result CSV's estimate and posterior std of the mean
            mean = np.trapezoid(d * grid, grid)
            std = math.sqrt(np.trapezoid(d * (grid - mean) ** 2, grid))
            assert mean == pytest.approx(r[p][i], rel=1e-5), (p, x["t"])
            assert std == pytest.approx(r[f"{p}_std"][i], rel=1e-4), (p, x["t"])
            compared += 1
        assert compared >= 5, p


def test_vehicle_pose_follows_the_truth(cosim_recording):
    r, rec, _ = cosim_recording
    body = temporal(rec, "/vehicle/body", "Transform3D:translation")
    xy = np.array([b["Transform3D:translation"][0][:2] for b in body])
    np.testing.assert_allclose(xy, np.column_stack([r["true_x"], r["true_y"]]), rtol=1e-6, atol=1e-4)
    q = np.array([b["Transform3D:quaternion"][0] for b in body])
    np.testing.assert_allclose(2 * np.arctan2(q[:, 2], q[:, 3]), r["true_psi"], atol=1e-6)
    steer = temporal(rec, "/vehicle/body/steer", "Transform3D:quaternion")
    np.testing.assert_allclose([2 * math.atan2(s["Transform3D:quaternion"][0][2], s["Transform3D:quaternion"][0][3])
                                for s in steer], r["true_delta"], atol=1e-6)
    assert len(temporal(rec, "/vehicle/trail", "Points3D:positions")) == len(r["t"])


def test_replay_with_rrd_lateral_model_gives_2d_clouds(cosim_recording, tmp_path):
    r, _, _ = cosim_recording
    log = write_log(tmp_path / "log.csv", {"t": r["t"], "delta": r["meas_delta"], "ax": r["meas_ax"],
                                            "ay": r["meas_ay"], "yaw_rate": r["meas_yaw_rate"], "vx": r["true_vx"]})
    out, rrd = tmp_path / "result.csv", tmp_path / "replay.rrd"
    assert main(["replay", str(log), "--vehicle", str(VEHICLE), "--model", "lateral", "--particles", "50",
                 "--out", str(out), "--rrd", str(rrd), "--log-every", "40", "--quiet"]) == 0
    res, rec = read_results(out), read_recording(rrd)
    t, cf = series(rec, "/estimator/mpf/stiffness/Cf_y")
    np.testing.assert_array_equal(cf, res["Cf_y"])
    assert "/estimator/mpf/stiffness/Cx" not in rec and "/estimator/mpf/density/Cx" not in rec
    for what in ("stiffness", "state"):
        rows = temporal(rec, f"/estimator/mpf/particles/{what}", "Points2D:positions")
        assert len(rows) == (len(res["t"]) - 1) // 40 + 1 and all(len(x["Points2D:positions"]) == 50 for x in rows)
    for p in ("Cf_y", "Cr_y"):
        assert len(temporal(rec, f"/estimator/mpf/density/{p}", "BarChart:values")) == len(rows)
    # no truth in a replay: the top view dead-reckons the estimated speed and yaw rate
    body = temporal(rec, "/vehicle/body", "Transform3D:translation")
    assert len(body) == len(res["t"]) and "/vehicle/x" not in rec
    psi = 2 * np.arctan2(*np.array([b["Transform3D:quaternion"][0] for b in body])[:, [2, 3]].T)
    dt = np.diff(res["t"], prepend=res["t"][0])
    np.testing.assert_allclose(np.unwrap(psi), np.cumsum(res["yaw_rate"] * dt), atol=1e-9)


# ---- friction curves and a Gaussian posterior, from a fake estimator ------------------------
class FakeFriction:
    """A friction estimator with a Gaussian stiffness posterior and no particles."""

    name = "fake"
    posterior_family = "gaussian"
    params = ("Cf_y", "Cr_y")

    def reset(self, rng):
        self.k = 0

    def step(self, t, u, y):
        self.k += 1
        self.t = t
        return Estimate(active=True, vx=u.vx, vy=0.0, yaw_rate=y.yaw_rate, Cf_y=4e4 + 10 * self.k,
                        Cr_y=5e4 - 5 * self.k, Cf_y_std=2e3 / math.sqrt(self.k), Cr_y_std=3e3 / math.sqrt(self.k),
                        b_ay=0.0, b_yaw_rate=0.0)

    def posterior(self):
        return Posterior(np.zeros((1, 2)), np.zeros(1), {"cov": np.eye(2)[None]})

    def friction(self):
        alpha = np.linspace(-0.2, 0.2, 81)
        mu = 0.3 * np.tanh(10 * alpha) * (1 + 0.001 * self.k)
        return FrictionCurve(self.t, alpha, mu, np.full(81, 0.02), 0.9 * mu, np.full(81, 0.03),
                             (-0.05, 0.06, -0.04, 0.05))


class Augmented(FakeFriction):
    """Particles that carry the stiffness as a state (as AUGPF): no NiW statistics."""

    name = "aug"
    posterior_family = None
    friction = None

    def reset(self, rng):
        super().reset(rng)
        self.rng = rng

    def posterior(self):
        x = np.column_stack([self.rng.normal(0, 0.1, 40), self.rng.normal(0, 0.01, 40)])  # (vy, r)
        C = np.column_stack([self.rng.normal(4e4, 2e3, 40), self.rng.normal(5e4, 2e3, 40)])
        return Posterior(x, self.rng.normal(size=40), {"stiffness": C, "params": ("Cf_y", "Cr_y")})


class NoPosterior(FakeFriction):
    """Neither posterior() nor friction(): series only."""

    name = "bare"
    posterior_family = None
    posterior = None
    friction = None


def test_fake_friction_estimator_curves_truth_and_gaussian_density(fmu_paths, tmp_path):
    scenario = load_scenario("friction-snow")
    from dataclasses import replace

    scenario = replace(scenario, duration=6.0)
    rrd = tmp_path / "fake.rrd"
    _, rows = run_scenario(scenario, estimator=FakeFriction(), seed=0, keep_rows=True,
                           recording=RecordingOptions(rrd=rrd, log_every=10))
    rec = read_recording(rrd)
    steps = len(rows)
    for axle, scale in (("front", 1.0), ("rear", 0.9)):
        curve = temporal(rec, f"/estimator/fake/friction/{axle}", "LineStrips3D:strips")
        band = temporal(rec, f"/estimator/fake/friction/{axle}/band", "LineStrips3D:strips")
        visited = temporal(rec, f"/estimator/fake/friction/{axle}/visited", "LineStrips3D:strips")
        truth = temporal(rec, f"/truth/friction/{axle}", "LineStrips3D:strips")
        assert len(curve) == len(band) == len(visited) == len(truth) == (steps - 1) // 10 + 1
        pts = np.array(curve[-1]["LineStrips3D:strips"][0])
        assert pts.shape == (81, 3)
        k = (steps - 1) // 10 * 10 + 1
        np.testing.assert_allclose(pts[:, 1], scale * 0.3 * np.tanh(10 * pts[:, 0]) * (1 + 0.001 * k), rtol=1e-6,
                                   atol=1e-7)
        assert len(band[-1]["LineStrips3D:strips"]) == 2
        x_visited = sorted({p[0] for s in visited[-1]["LineStrips3D:strips"] for p in s})
        np.testing.assert_allclose(x_visited, (-0.05, 0.06) if axle == "front" else (-0.04, 0.05), rtol=1e-6)
        true_pts = np.array(truth[-1]["LineStrips3D:strips"][0])
        np.testing.assert_allclose(true_pts[:, 1], pure_lateral_friction(scenario.model.pacejka, true_pts[:, 0]),
                                   rtol=1e-5, atol=1e-6)
    assert "/estimator/fake/particles/stiffness" not in rec  # one Gaussian: no cloud
    grid = np.asarray([x for x in rec["/estimator/fake/density/Cf_y"] if x["t"] is None][0]["BarChart:abscissa"][0]
                      ["buffer"], float)
    dens = temporal(rec, "/estimator/fake/density/Cf_y", "BarChart:values")
    last = np.asarray(dens[-1]["BarChart:values"][0]["buffer"], float)
    k = (steps - 1) // 10 * 10 + 1
    expected = stats.norm.pdf(grid, 4e4 + 10 * k, 2e3 / math.sqrt(k))
    # the abscissa is stored as float32: 1e-4 of the peak covers its rounding on the flanks
    np.testing.assert_allclose(last, expected, rtol=1e-5, atol=1e-4 * expected.max())

    rrd3 = tmp_path / "aug.rrd"
    run_scenario(scenario, estimator=Augmented(), seed=0, recording=RecordingOptions(rrd=rrd3, log_every=10))
    rec3 = read_recording(rrd3)
    for what in ("stiffness", "state"):  # 2-D clouds of the 40 particles
        rows3 = temporal(rec3, f"/estimator/aug/particles/{what}", "Points2D:positions")
        assert len(rows3) == (steps - 1) // 10 + 1 and all(len(x["Points2D:positions"]) == 40 for x in rows3)
    _, mass = series(rec3, "/estimator/aug/density/Cr_y/mass")  # the weighted KDE, within the grid
    assert len(mass) == len(rows3) and np.all(mass > 1 - 1e-9)

    rrd2 = tmp_path / "bare.rrd"
    run_scenario(scenario, estimator=NoPosterior(), seed=0, recording=RecordingOptions(rrd=rrd2, log_every=10))
    rec2 = read_recording(rrd2)
    assert "/estimator/bare/stiffness/Cf_y" in rec2
    assert not [p for p in rec2 if p.startswith(("/estimator/bare/particles", "/estimator/bare/density",
                                                 "/estimator/bare/friction"))]


# ---- options and live streaming ---------------------------------------------------------------
def test_bad_recording_options_are_refused(capsys):
    with pytest.raises(ConfigError, match="log-every"):
        RecordingOptions(rrd="x.rrd", log_every=0).validated()
    with pytest.raises(ConfigError, match="rerun\\+http://127.0.0.1:9876/proxy"):
        RecordingOptions(connect="127.0.0.1:9876").validated()
    assert main(["run", "--scenario", "paper-sim", "--connect", "localhost:1", "--quiet"]) == 1
    assert "--connect" in capsys.readouterr().err


def test_a_viewer_that_cannot_start_is_a_clear_error(monkeypatch, tmp_path):
    import tirefilter.viz.rerun_log as rerun_log

    monkeypatch.setattr(rerun_log, "_bundled_viewer", lambda: "/bin/false")
    with pytest.raises(ConfigError, match="--spawn.*exited with status 1"):
        rerun_log.RerunRecorder(RecordingOptions(spawn=True, spawn_port=_free_port()), ("t",), None)


def test_connect_to_nothing_fails_before_the_run(fmu_paths, tmp_path, capsys):
    url = f"rerun+http://127.0.0.1:{_free_port()}/proxy"
    t0 = time.monotonic()
    assert main(["run", "--scenario", "paper-sim", "--out", str(tmp_path / "run"), "--connect", url, "--quiet"]) == 1
    assert time.monotonic() - t0 < 10
    err = capsys.readouterr().err
    assert "--connect" in err and "nothing accepts connections" in err and url in err


def _wait_until_written(path: Path, timeout: float = 20.0) -> None:
    """Until the receiver's file has stopped growing for a second."""
    deadline, size, since = time.monotonic() + timeout, -1, time.monotonic()
    while time.monotonic() < deadline:
        now = path.stat().st_size if path.is_file() else -1
        if now != size:
            size, since = now, time.monotonic()
        elif size > 0 and time.monotonic() - since > 1.0:
            return
        time.sleep(0.1)


def _receiver() -> str:
    """The rerun binary of rerun-sdk (not the rerun_cli wrapper, whose pid is not the server's)."""
    from tirefilter.viz.rerun_log import _bundled_viewer

    exe = _bundled_viewer()
    if exe is None:
        pytest.skip("rerun-sdk ships no rerun binary on this platform")
    return exe


def _stop(pid: int) -> None:
    """SIGINT (the receiver finishes its file), then SIGKILL after 10 s; reaps it when it
    is a child of this process."""
    os.kill(pid, signal.SIGINT)
    for _ in range(100):
        try:
            if os.waitpid(pid, os.WNOHANG)[0] == pid:
                return
        except ChildProcessError:  # not our child: poll its existence
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                return
        time.sleep(0.1)
    os.kill(pid, signal.SIGKILL)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_connect_streams_to_a_local_grpc_receiver(fmu_paths, tmp_path):
    """--connect against a viewer-less receiver: the rerun CLI of rerun-sdk serving gRPC on
    127.0.0.1 and saving what arrives (`rerun --bind 127.0.0.1 --port P --save FILE`)."""
    port, received = _free_port(), tmp_path / "received.rrd"
    env = dict(os.environ, HOME=str(tmp_path), XDG_CONFIG_HOME=str(tmp_path / "config"),
               XDG_DATA_HOME=str(tmp_path / "data"))  # its first-run state stays in the test's folder
    server = subprocess.Popen([_receiver(), "--bind", "127.0.0.1", "--port", str(port),
                               "--save", str(received)], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
                break
            except OSError:
                assert time.monotonic() < deadline and server.poll() is None, "receiver did not start"
                time.sleep(0.1)
        out = tmp_path / "run"
        assert main(["run", "--scenario", str(_short_scenario(tmp_path, 3.0)), "--particles", "30", "--out", str(out),
                     "--connect", f"rerun+http://127.0.0.1:{port}/proxy", "--log-every", "50", "--quiet"]) == 0
        r = read_results(out / "results.csv")
        _wait_until_written(received)
    finally:
        server.send_signal(signal.SIGINT)
        try:
            server.wait(timeout=20)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()
    rec = read_recording(received)
    t, cf = series(rec, "/estimator/mpf/stiffness/Cf_y")
    np.testing.assert_array_equal(cf, r["Cf_y"])
    assert len(temporal(rec, "/estimator/mpf/particles/stiffness", "Points3D:positions")) == (len(r["t"]) - 1) // 50 + 1


def test_spawn_starts_a_viewer_process_and_streams_to_it(fmu_paths, tmp_path, monkeypatch):
    """--spawn with --rrd: the viewer executable is started on 127.0.0.1 and the port, then
    the recording goes to both sinks. The 'viewer' here is the same viewer-less receiver,
    started through a wrapper that records its pid and arguments (no display in the tests)."""
    import tirefilter.viz.rerun_log as rerun_log

    port, received, pid_file = _free_port(), tmp_path / "spawned.rrd", tmp_path / "viewer.pid"
    wrapper = tmp_path / "viewer.sh"
    wrapper.write_text(f"#!/bin/sh\necho $$ > {pid_file}\necho \"$@\" > {tmp_path}/args\n"
                       f"export HOME={tmp_path} XDG_CONFIG_HOME={tmp_path}/config XDG_DATA_HOME={tmp_path}/data\n"
                       f"exec {_receiver()} --save {received} \"$@\" >/dev/null 2>&1\n")
    wrapper.chmod(0o755)
    monkeypatch.setattr(rerun_log, "_bundled_viewer", lambda: str(wrapper))
    scenario = load_scenario(_short_scenario(tmp_path, 2.0))
    from tirefilter.estimators import build_estimator

    est = build_estimator("mpf", scenario, model="auto", particles=20, config={})
    rrd = tmp_path / "file.rrd"
    try:
        _, rows = run_scenario(scenario, estimator=est, seed=1, keep_rows=True,
                               recording=RecordingOptions(rrd=rrd, spawn=True, spawn_port=port, log_every=20))
        _wait_until_written(received)
    finally:
        deadline = time.monotonic() + 10
        while not pid_file.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        _stop(int(pid_file.read_text()))
    assert f"--bind 127.0.0.1 --port {port}" in (tmp_path / "args").read_text()  # the viewer listens on loopback
    for path in (rrd, received):
        t, cf = series(read_recording(path), "/estimator/mpf/stiffness/Cf_y")
        np.testing.assert_array_equal(cf, rows[:, 6])  # ESTIMATE_COLUMNS: t, active, vx, vy, yaw_rate, beta, Cf_y


# ---- every registered estimator records --------------------------------------------------------
KINDS = {"mpf": "eq26", "augpf": "kde", "rls": "gaussian", "ekf": "gaussian", "kf": None, "gpssm": None,
         "combined": None}


@pytest.mark.parametrize("name", [e for e in __import__("tirefilter.estimators", fromlist=["ESTIMATORS"]).ESTIMATORS
                                  if e != "none"])
def test_every_estimator_records_its_series_and_what_its_posterior_supports(fmu_paths, tmp_path, name):
    from tirefilter.estimators import build_estimator

    scenario = load_scenario(_short_scenario(tmp_path, 2.0))
    model = "lateral" if name in ("kf", "rls", "gpssm", "combined") else "auto"
    est = build_estimator(name, scenario, model=model, particles=30, config={})
    rrd = tmp_path / "e.rrd"
    _, rows = run_scenario(scenario, estimator=est, seed=2, keep_rows=True,
                           recording=RecordingOptions(rrd=rrd, log_every=50))
    rec = read_recording(rrd)
    e, logged = est.name, (len(rows) - 1) // 50 + 1
    t, cf = series(rec, f"/estimator/{e}/stiffness/Cf_y")
    np.testing.assert_array_equal(cf, rows[:, 6][~np.isnan(rows[:, 6])])
    density = [p for p in rec if p.startswith(f"/estimator/{e}/density/") and not p.endswith("/mass")]
    if KINDS[name] is None:
        assert not density
    else:
        assert density and all(len(temporal(rec, p, "BarChart:values")) == logged for p in density)
        for p in density:
            _, mass = series(rec, p + "/mass")
            grid = np.asarray([x for x in rec[p] if x["t"] is None][0]["BarChart:abscissa"][0]["buffer"], float)
            for x, m in zip(temporal(rec, p, "BarChart:values"), mass):
                assert abs(np.trapezoid(np.asarray(x["BarChart:values"][0]["buffer"], float), grid) - m) < 1e-3
    clouds = KINDS[name] in ("eq26", "kde") or name in ("gpssm", "combined")
    state = [r for r in rec.get(f"/estimator/{e}/particles/state", []) if r["t"] is not None]
    assert (len(state) == logged) if clouds else not state
    friction = f"/estimator/{e}/friction/front" in rec
    assert friction == (name in ("gpssm", "combined"))
    if friction:
        assert len(temporal(rec, "/truth/friction/rear", "LineStrips3D:strips")) == logged


def test_stiffness_y_ranges_fit_the_data_after_the_start_up(tmp_path):
    """The stiffness plots' y range: 0.5-99.5% quantiles of estimate and true mean from
    STARTUP_S on, widened by 15% each side (at least 5% of the mean); the start-up
    transient is left out."""
    from tirefilter.viz.rerun_log import STARTUP_S, RerunRecorder

    t = np.arange(0, 1001) * 0.01
    est = np.where(t < 1.0, 6e5, 1e5 + 1e3 * np.sin(t))  # a transient to 6e5, then 1e5 +- 1e3
    truth = np.full(t.shape, 1.01e5)
    rec = RerunRecorder(tmp_path / "r.rrd", ("t", "Cx", "true_Cx_mean"), "mpf", chunk=300)
    for row in zip(t, est, truth):
        rec.write(row)
    rec.flush()
    after = t >= STARTUP_S
    lo, hi = np.quantile(np.concatenate([est[after], truth[after]]), [0.005, 0.995])
    pad = max(0.15 * (hi - lo), 0.05 * abs(0.5 * (lo + hi)))  # here 5% of the mean: the data span 2%
    assert pad == 0.05 * abs(0.5 * (lo + hi))
    assert rec.y_ranges() == {"Cx": (pytest.approx(lo - pad), pytest.approx(hi + pad))}
    assert rec.y_ranges()["Cx"][1] < 1.1e5  # not the transient's 6e5
    rec.close()


def test_density_history_is_every_snapshot_scaled_to_its_peak_and_cropped(tmp_path):
    from tirefilter.viz.rerun_log import _VIRIDIS_LUT, HISTORY_SHAPE, RerunRecorder

    rec = RerunRecorder(tmp_path / "d.rrd", ("t",), "mpf")
    grid = np.linspace(0.0, 100.0, 101)
    rec._grids["Cf_y"] = grid
    d0 = np.exp(-0.5 * ((grid - 40.0) / 2.0) ** 2)  # 1% of the peak at 40 +- 6.07
    d1 = 3.0 * np.exp(-0.5 * ((grid - 50.0) / 2.0) ** 2)
    rec._history["Cf_y"] = [(0.0, d0.astype(np.float32)), (1.0, d1.astype(np.float32))]
    h = rec.density_history()["Cf_y"]
    # used rows: 34 .. 56 (above 1% of a peak), two grid points of margin below, three above (exclusive end)
    assert h["range"] == (32.0, 58.0) and h["t"] == (0.0, 1.0)
    assert h["image"].shape == HISTORY_SHAPE + (3,) and h["image"].dtype == np.uint8
    # the peak of each snapshot is the LUT's top colour; stiffness grows upwards
    rows = np.linspace(0, 26, HISTORY_SHAPE[0]).round().astype(int)
    first = h["image"][:, 0]
    top = np.flatnonzero((first == _VIRIDIS_LUT[255]).all(axis=1))
    assert len(top) and all(grid[32 + 26 - rows[r]] == 40.0 for r in top)
    last = h["image"][:, -1]
    top = np.flatnonzero((last == _VIRIDIS_LUT[255]).all(axis=1))
    assert len(top) and all(grid[32 + 26 - rows[r]] == 50.0 for r in top)
    rec.close()
