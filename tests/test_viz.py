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


def test_mixture_std_and_quantiles_against_brute_force():
    """The std of eq. (26) (per component scale^2 df / (df - 2) plus the spread of the means) and
    its quantiles (the mixture's CDF inverted), against scipy's Student-t densities summed."""
    s = _niw(seed=5, N=60)
    mix = niw_mean_marginals(**s)
    w = np.exp(s["log_weights"] - s["log_weights"].max())
    w /= w.sum()
    for j, p in enumerate(s["params"]):
        scale = mix.scale[:, j]
        comps = [stats.t(mix.df[i], loc=mix.loc[i, j], scale=scale[i]) for i in range(len(w))]
        m = sum(wi * c.mean() for wi, c in zip(w, comps))
        var = sum(wi * (c.var() + (c.mean() - m) ** 2) for wi, c in zip(w, comps))
        assert mix.std(p) == pytest.approx(math.sqrt(var), rel=1e-10)
        q = mix.quantiles(p, [0.05, 0.5, 0.95])
        cdf = [sum(wi * c.cdf(x) for wi, c in zip(w, comps)) for x in q]
        np.testing.assert_allclose(cdf, [0.05, 0.5, 0.95], atol=1e-9)
    g = gaussian_marginals([0.0], [[10.0]], [[2.0]], ("a",))
    np.testing.assert_allclose(g.quantiles("a", [0.05, 0.95]), stats.norm.ppf([0.05, 0.95], 10.0, 2.0), rtol=1e-10)


def test_quantiles_of_a_lumpy_mixture_from_a_grid_start():
    """Narrow particles far apart (a lumpy mixture): the quantiles from the grid's start and
    from the normal approximation agree to the tolerance asked, and hold the mass asked by
    scipy's Student-t CDFs summed."""
    from tirefilter.viz.density import Mixture, grid_quantiles, window_grid

    rng = np.random.default_rng(7)
    M = 40
    loc, scale, df = rng.normal(1e5, 2e4, M), rng.uniform(20.0, 80.0, M), rng.uniform(5.0, 40.0, M)
    w = rng.dirichlet(np.ones(M))
    mix = Mixture(("a",), w, loc[:, None], scale[:, None], df, "t")
    q = [0.05, 0.5, 0.95]
    exact = mix.quantiles("a", q)
    grid = window_grid(mix.mean("a"), mix.std("a"), 4.0, 1601)
    start = grid_quantiles(mix, "a", grid, mix.pdf("a", grid), q)
    assert np.all(np.abs(start - exact) < 0.05 * mix.std("a"))  # the trapezoid's guess
    polished = mix.quantiles("a", q, start=start, rtol=1e-6)
    np.testing.assert_allclose(polished, exact, rtol=0, atol=1e-6 * mix.std("a"))
    cdf = [sum(wi * stats.t.cdf(x, d, loc=l, scale=s) for wi, l, s, d in zip(w, loc, scale, df)) for x in exact]
    np.testing.assert_allclose(cdf, q, atol=1e-9)


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


def documented_paths(e: str, params, lateral: bool, bias_note: bool = True) -> list[str]:
    """The table of docs/rerun.md, for estimator `e` (kept in step with it by
    test_docs_list_every_documented_path)."""
    out = [f"/truth/{c}" for c in ("vx", "vy", "yaw_rate", "beta", "alpha_f", "alpha_r", "Cf_y", "Cr_y", "Cx",
                                   "Cf_y_mean", "Cr_y_mean", "Cx_mean", "b_ax", "b_ay", "b_yaw_rate", "delta")]
    out += [f"/sensors/{s}" for s in ("ax", "ay", "yaw_rate", "omega_f", "omega_r", "delta")]
    out += ["/vehicle/x", "/vehicle/y", "/vehicle/psi", "/vehicle/path", "/vehicle/scale", "/vehicle/trail",
            "/vehicle/body", "/vehicle/body/outline", "/vehicle/body/shape", "/vehicle/body/heading",
            "/vehicle/body/steer",
            "/vehicle/body/marker", "/vehicle/body/velocity", "/vehicle/body/velocity_estimate", "/vehicle/position",
            "/vehicle/position/frame", "/vehicle/position/scale"]
    b = f"/estimator/{e}"
    out += [f"{b}/state/{s}" for s in ("vx", "vy", "yaw_rate", "beta")]
    out += [f"{b}/bias/{s}" for s in ("ay", "yaw_rate") + (() if lateral else ("ax",))]
    out += [f"{b}/ess", f"{b}/ess/particles", f"{b}/ess/threshold", f"{b}/active"]
    out += [f"{b}/particles/{w}" for w in ("stiffness", "state", "stiffness_axes", "stiffness_axes/labels",
                                           "stiffness_axes/weight_scale", "state_axes")]
    out += [f"{b}/notes/bias"] if bias_note else []
    for p in params:
        out += [f"{b}/stiffness/{p}", f"{b}/stiffness/{p}_std", f"{b}/stiffness/{p}_sigma", f"{b}/density/{p}",
                f"{b}/density/{p}/mass", f"{b}/density/{p}/true_mean", f"{b}/density/{p}/q05",
                f"{b}/density/{p}/q95"]
        out += [f"{b}/stiffness/{p}/{w}_{s}" for w in ("posterior", "spread") for s in ("lower", "upper")]
    return out


def read_blueprints(path) -> list[dict[str, dict]]:
    """The blueprints of a recording, the first step's before the final one, each as view title ->
    {"class", "origin", "contents" (queries), "range" (y axis or None), "legend" (visible or
    None), "names" (entity -> its series names), "eye" (EyeControls3D fields)}; the
    containers as "<tabs>" -> their names."""
    from rerun.chunk import RrdReader

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = RrdReader(path)
    out = []
    for store in reader.blueprints():
        views: dict[str, dict] = {}
        for chunk in reader.stream(store=store).collect().stream():
            batch = chunk.to_record_batch()
            cols = {n: batch.column(n).to_pylist()[-1] for n in batch.schema.names if ":" in n}
            parts = chunk.entity_path.strip("/").split("/")
            if parts[0] != "view":
                if parts[0] == "container" and "ContainerBlueprint:display_name" in cols:
                    views.setdefault("<tabs>", {}).setdefault("names", []).append(
                        cols["ContainerBlueprint:display_name"][0])
                continue
            v = views.setdefault(parts[1], {"names": {}, "eye": {}, "range": None, "legend": None})
            if len(parts) == 2:
                v.update({"title": cols["ViewBlueprint:display_name"][0],
                          "class": cols["ViewBlueprint:class_identifier"][0],
                          "origin": cols["ViewBlueprint:space_origin"][0]})
            elif parts[2] == "ScalarAxis" and cols.get("ScalarAxis:range"):
                v["range"] = tuple(cols["ScalarAxis:range"][0])
            elif parts[2] == "PlotLegend" and cols.get("PlotLegend:visible"):
                v["legend"] = cols["PlotLegend:visible"][0]
            elif parts[2] == "VisibleTimeRanges":
                v["time_ranges"] = True
            elif parts[2] == "EyeControls3D":
                v["eye"].update({k.split(":")[1]: x[0] if x else None for k, x in cols.items()})
            elif parts[2] == "ViewContents" and len(parts) == 3:
                v["contents"] = cols["ViewContents:query"]
            elif parts[2] == "ViewContents" and "overrides" in parts and "SeriesLines:names" in cols:
                entity = "/" + "/".join(parts[4:parts.index("visualizers")])
                v["names"][entity] = cols["SeriesLines:names"]
            elif parts[2] == "ViewContents" and "overrides" in parts and "SeriesPoints:names" in cols:
                entity = "/" + "/".join(parts[4:parts.index("visualizers")])
                v["names"][entity] = cols["SeriesPoints:names"]
        out.append({v["title"]: v for k, v in views.items() if "title" in v} | {"<tabs>": views.get("<tabs>", {})})
    # the root container names the blueprint: "tirefilter layout (first step)" or "(final)"
    return sorted(out, key=lambda b: "tirefilter layout (final)" in b["<tabs>"].get("names", []))


@pytest.fixture(scope="module")
def cosim_recording(fmu_paths, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("viz")
    out, rrd = tmp / "run", tmp / "run.rrd"
    assert main(["run", "--scenario", str(_short_scenario(tmp)), "--particles", str(N), "--seed", "4", "--out",
                 str(out), "--rrd", str(rrd), "--log-every", str(K), "--quiet"]) == 0
    return read_results(out / "results.csv"), read_recording(rrd), rrd


def test_recorded_series_equal_the_result_csv_in_the_recording_units(cosim_recording):
    """Every column is recorded as in the CSV times `viz.units.scale`: stiffness in kN/rad and
    kN per unit slip (not raw N: "200 000"), beta and the slip angles in degrees, the rest SI."""
    from tirefilter.viz.paths import entity_path
    from tirefilter.viz.units import DEG, KILO, scale

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
        np.testing.assert_array_equal(v, values[keep] * scale(column), err_msg=path)
        checked += 1
    assert checked > 60
    assert scale("Cx") == scale("Cf_y_std") == scale("true_Cx_mean") == KILO and scale("vy") == 1.0
    assert scale("beta") == scale("true_beta") == DEG
    _, cx = series(rec, "/estimator/mpf/stiffness/Cx")
    assert 50 < np.median(cx) < 1000  # kN per unit slip, not N
    # the bands are the 90 % band of the mean (+-1.645 std) and the 90 % range of the per-step stiffness
    t, lower = series(rec, "/estimator/mpf/stiffness/Cf_y/posterior_lower")
    np.testing.assert_allclose(lower, (r["Cf_y"] - 1.6448536269514722 * r["Cf_y_std"]) * 1e-3, rtol=1e-12)
    t, upper = series(rec, "/estimator/mpf/stiffness/Cr_y/spread_upper")
    np.testing.assert_allclose(upper, (r["Cr_y"] + 1.6448536269514722 * r["Cr_y_sigma"]) * 1e-3, rtol=1e-12)


def test_every_documented_path_exists_with_a_blueprint(cosim_recording):
    _, rec, rrd = cosim_recording
    missing = [p for p in documented_paths("mpf", ("Cf_y", "Cr_y", "Cx"), lateral=False) if p not in rec]
    assert not missing
    from rerun.chunk import RrdReader

    assert len(RrdReader(rrd).blueprints()) == 2  # the first at the first step, the final one at the end


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


def _bars(row):
    """(abscissa, values, widths) of a BarChart row."""
    return tuple(np.asarray(row[f"BarChart:{k}"][0]["buffer"] if k != "widths" else row[f"BarChart:{k}"], float)
                 for k in ("abscissa", "values", "widths"))


def test_particles_and_densities_hold_the_expected_points_per_logged_step(cosim_recording):
    """Per logged step: N particles with colours; per parameter the density of eq. (26) on a
    physical axis (kN) over the posterior's mean -+ 4 std, which are the CSV's estimate and
    `*_std` (not a hairline on a fixed 0 .. 360 kN axis), holding the exact mass of that
    window; the true surface mean as one bar as high as the peak; the 5 % and 95 % quantiles."""
    from tirefilter.viz.rerun_log import DENSITY_REACH

    r, rec, _ = cosim_recording
    steps = len(r["t"])
    logged_t = r["t"][::K]
    for what in ("stiffness", "state"):
        rows = temporal(rec, f"/estimator/mpf/particles/{what}", "Points3D:positions")
        np.testing.assert_allclose([x["t"] for x in rows], logged_t, atol=1e-9)
        assert all(len(x["Points3D:positions"]) == N and len(x["Points3D:colors"]) == N for x in rows)
    assert len(logged_t) == (steps - 1) // K + 1
    i_csv = np.searchsorted(r["t"], logged_t - 1e-9)
    for p in ("Cf_y", "Cr_y", "Cx"):
        entity = f"/estimator/mpf/density/{p}"
        rows = temporal(rec, entity, "BarChart:values")
        np.testing.assert_allclose([x["t"] for x in rows], logged_t, atol=1e-9)
        t_mass, exact = series(rec, f"{entity}/mass")
        np.testing.assert_allclose(t_mass, logged_t, atol=1e-9)
        truth = temporal(rec, f"{entity}/true_mean", "BarChart:values")
        _, q05 = series(rec, f"{entity}/q05")
        _, q95 = series(rec, f"{entity}/q95")
        assert len(truth) == len(q05) == len(q95) == len(rows)
        for x, i, inside, tr, lo, hi in zip(rows, i_csv, exact, truth, q05, q95):
            grid, d, widths = _bars(x)
            assert d.shape == grid.shape == (RecordingOptions().density_points,)
            mean, std = r[p][i] * 1e-3, r[f"{p}_std"][i] * 1e-3  # kN
            # the window is the posterior's mean -+ 4 std: the Result CSV's estimate and std (float32 storage)
            assert grid[0] == pytest.approx(mean - DENSITY_REACH * std, rel=1e-6, abs=1e-5 * std)
            assert grid[-1] == pytest.approx(mean + DENSITY_REACH * std, rel=1e-6, abs=1e-5 * std)
            np.testing.assert_allclose(widths, grid[1] - grid[0], rtol=1e-3)  # float32 abscissa
            # eq. (26) per kN on the window holds the exact probability of the window (the components' CDFs)
            assert abs(np.trapezoid(d, grid) - inside) < 1e-3, (p, x["t"])
            assert inside > 0.9
            # the true surface mean: one bar, as high as the density's peak
            tgrid, tval, _ = _bars(tr)
            assert tgrid == pytest.approx([r[f"true_{p}_mean"][i] * 1e-3], rel=1e-6)
            assert tval[0] == pytest.approx(d.max())
            # the quantiles hold 5 % of the density below and above them
            assert lo < mean < hi
            below = np.trapezoid(np.where(grid <= lo, d, 0.0), grid) + (1 - inside) / 2
            assert below == pytest.approx(0.05, abs=0.01), (p, x["t"])


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
    np.testing.assert_array_equal(cf, res["Cf_y"] * 1e-3)  # kN/rad
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
    grid, last, _ = _bars(temporal(rec, "/estimator/fake/density/Cf_y", "BarChart:values")[-1])
    k = (steps - 1) // 10 * 10 + 1
    m, s = (4e4 + 10 * k) * 1e-3, 2e3 / math.sqrt(k) * 1e-3  # kN/rad
    np.testing.assert_allclose(grid[[0, -1]], [m - 4 * s, m + 4 * s], rtol=1e-6)
    expected = stats.norm.pdf(grid, m, s)  # per kN/rad
    # the abscissa is stored as float32: 1e-4 of the peak covers its rounding on the flanks
    np.testing.assert_allclose(last, expected, rtol=1e-5, atol=1e-4 * expected.max())
    # its quantiles are the Gaussian's, exactly (the mixture's CDF inverted)
    _, q05 = series(rec, "/estimator/fake/density/Cf_y/q05")
    _, q95 = series(rec, "/estimator/fake/density/Cf_y/q95")
    assert q05[-1] == pytest.approx(m - 1.6448536269514722 * s, rel=1e-9)
    assert q95[-1] == pytest.approx(m + 1.6448536269514722 * s, rel=1e-9)

    rrd3 = tmp_path / "aug.rrd"
    run_scenario(scenario, estimator=Augmented(), seed=0, recording=RecordingOptions(rrd=rrd3, log_every=10))
    rec3 = read_recording(rrd3)
    for what in ("stiffness", "state"):  # 2-D clouds of the 40 particles
        rows3 = temporal(rec3, f"/estimator/aug/particles/{what}", "Points2D:positions")
        assert len(rows3) == (steps - 1) // 10 + 1 and all(len(x["Points2D:positions"]) == 40 for x in rows3)
    _, mass = series(rec3, "/estimator/aug/density/Cr_y/mass")  # the weighted KDE within its mean -+ 4 std
    assert len(mass) == len(rows3) and np.all(mass > 0.999)  # measured: at least 0.9996

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
    np.testing.assert_array_equal(cf, r["Cf_y"] * 1e-3)  # kN/rad
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
        # kN/rad; ESTIMATE_COLUMNS: t, active, vx, vy, yaw_rate, beta, Cf_y
        np.testing.assert_array_equal(cf, rows[:, 6] * 1e-3)


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
    np.testing.assert_array_equal(cf, rows[:, 6][~np.isnan(rows[:, 6])] * 1e-3)
    density = [p for p in rec if re.fullmatch(f"/estimator/{e}/density/[^/]+", p)]
    if KINDS[name] is None:
        assert not density
    else:
        assert density and all(len(temporal(rec, p, "BarChart:values")) == logged for p in density)
        for p in density:
            _, mass = series(rec, p + "/mass")
            _, q05 = series(rec, p + "/q05")
            for x, m in zip(temporal(rec, p, "BarChart:values"), mass):
                grid, values, _ = _bars(x)
                assert abs(np.trapezoid(values, grid) - m) < 1e-3
            assert len(q05) == logged
    clouds = KINDS[name] in ("eq26", "kde") or name in ("gpssm", "combined")
    state = [r for r in rec.get(f"/estimator/{e}/particles/state", []) if r["t"] is not None]
    assert (len(state) == logged) if clouds else not state
    friction = f"/estimator/{e}/friction/front" in rec
    assert friction == (name in ("gpssm", "combined"))
    if friction:
        assert len(temporal(rec, "/truth/friction/rear", "LineStrips3D:strips")) == logged


def test_y_ranges_fit_the_data_after_the_start_up(tmp_path):
    """Each series view's y range: 0.5-99.5% quantiles of its data (estimate, truth, measured)
    from STARTUP_S on, widened by 15% each side (at least 5% of the mid value), then out to
    round values (`snap_range`); the start-up transient is left out (the a^Y bias and vy
    plots were squashed by their start-up spikes)."""
    from tirefilter.viz.rerun_log import STARTUP_S, RerunRecorder, robust_range, snap_range

    t = np.arange(0, 1001) * 0.01
    est = np.where(t < 1.0, 6e5, 1e5 + 1e3 * np.sin(t))  # a transient to 6e5, then 1e5 +- 1e3
    truth = np.full(t.shape, 1.01e5)
    vy = np.where(t < 1.0, -4.0, 0.5 * np.sin(3 * t))  # a start-up spike to -4 m/s, then +-0.5
    rec = RerunRecorder(tmp_path / "r.rrd", ("t", "Cx", "true_Cx_mean", "vy", "true_vy"), "mpf", chunk=300)
    for row in zip(t, est, truth, vy, vy * 0.9):
        rec.write(row)
    rec.flush()
    after = t >= STARTUP_S
    lo, hi = np.quantile(np.concatenate([est[after], truth[after]]) * 1e-3, [0.005, 0.995])  # kN
    pad = max(0.15 * (hi - lo), 0.05 * abs(0.5 * (lo + hi)))  # here 5% of the mean: the data span 2%
    assert pad == 0.05 * abs(0.5 * (lo + hi))
    ranges = rec.y_ranges()
    assert ranges["Cx"] == pytest.approx(snap_range(lo - pad, hi + pad))
    assert ranges["Cx"] == pytest.approx((90.0, 110.0))  # 95.1 .. 105.9 out to multiples of 10
    assert ranges["vy"] == pytest.approx((-1.0, 1.0))  # -0.65 .. 0.65 out to multiples of 1, not the spike's -4
    assert ranges["vy"] == pytest.approx(robust_range(np.concatenate([vy[after], 0.9 * vy[after]])))
    assert robust_range(np.zeros(10)) is None  # flat data: the view fits itself
    assert snap_range(104.6, 289.7) == (100.0, 300.0) and snap_range(-0.02, 1.03) == (-0.02, 1.03)  # not tripled
    rec.close()


# ---- a recording that explains itself: layout first, titles, legends, notes, clouds, top view ----------
def test_the_blueprint_comes_before_the_data(tmp_path):
    """A viewer that opens the file while it is written (or watches a live stream) gets the
    layout with the first step, not Rerun's automatic grid of every entity until the end of
    the run; the final blueprint (y ranges, notes) follows at the end."""
    from types import SimpleNamespace

    from tirefilter.io.results import ESTIMATE_COLUMNS, estimate_values
    from tirefilter.viz.rerun_log import RerunRecorder

    path = tmp_path / "live.rrd"
    rec = RerunRecorder(path, ESTIMATE_COLUMNS, "fake")
    est = FakeFriction()
    est.reset(None)
    e = est.step(0.0, SimpleNamespace(vx=20.0), SimpleNamespace(yaw_rate=0.1))
    rec.stepped(est, e)
    rec.write(estimate_values(0.0, e))
    rec.rec.flush()
    early = read_blueprints(path)  # the file as it stands during the run
    assert len(early) == 1 and {"Cf_y [kN/rad]", "Cr_y [kN/rad]", "vy [m/s]", "ESS [particles]"} <= set(early[0])
    rec.close()
    final = read_blueprints(path)
    assert len(final) == 2 and set(final[0]) == set(final[1])


def test_titles_are_short_with_units_and_legends_name_every_series(cosim_recording):
    from tirefilter.viz.blueprint import BAND_OF_MEAN, PER_STEP, TITLE_MAX

    r, _, rrd = cosim_recording
    first, final = read_blueprints(rrd)
    views = {k: v for k, v in final.items() if k != "<tabs>"}
    assert all(len(title) <= TITLE_MAX for title in views), [t for t in views if len(t) > TITLE_MAX]
    for title in ("Cx [kN/unit slip]", "Cf_y [kN/rad]", "Cr_y [kN/rad]", "vx [m/s]", "vy [m/s]", "beta [deg]",
                  "yaw rate [rad/s]", "ESS [particles]", "density of Cx [kN/unit slip]",
                  "Cf_y posterior over time [kN/rad]"):
        assert title in views, title
    for title, v in views.items():
        if v["class"] in ("TimeSeries", "BarChart"):
            assert v["legend"] is True, title  # the key is a legend, never a cut-off title
    names = views["Cf_y [kN/rad]"]["names"]
    b = "/estimator/mpf/stiffness/Cf_y"
    assert names[b] == ["estimate"] and names["/truth/Cf_y_mean"] == ["true surface mean"]
    assert names[f"{b}/posterior_lower"] == names[f"{b}/posterior_upper"] == [BAND_OF_MEAN]  # one legend entry
    assert names[f"{b}/spread_lower"] == names[f"{b}/spread_upper"] == [PER_STEP]
    assert views["vx [m/s]"]["names"]["/sensors/vx"] == ["measured"]
    assert set(first) == set(final)  # the first blueprint has the same views


def test_bias_panels_say_not_estimated_when_the_estimator_does_not_estimate_them(cosim_recording, fmu_paths, tmp_path):
    """paper-sim's MPF takes the IMU as unbiased: a note instead of flat zero 'estimates'; an
    estimator with bias estimates gets them per channel with units."""
    from tirefilter.viz.rerun_log import BIAS_NOTE

    _, rec, rrd = cosim_recording
    note = [x for x in rec["/estimator/mpf/notes/bias"] if "TextDocument:text" in x][0]["TextDocument:text"][0]
    assert note == BIAS_NOTE and "not estimated" in note.lower()
    final = read_blueprints(rrd)[-1]
    text_views = [v for v in final.values() if v.get("class") == "TextDocument"]
    assert [v["origin"] for v in text_views] == ["/estimator/mpf/notes/bias"]
    queries = [q for v in final.values() for q in v.get("contents", [])]
    assert not [q for q in queries if "/bias/" in q], queries  # no zero lines of a bias that is not estimated
    scenario = load_scenario(_short_scenario(tmp_path, 1.0))
    rrd2 = tmp_path / "fake.rrd"
    run_scenario(scenario, estimator=FakeFriction(), seed=0, recording=RecordingOptions(rrd=rrd2, log_every=50))
    views = read_blueprints(rrd2)[-1]
    assert {"bias ay [m/s²]", "bias yaw rate [rad/s]"} <= set(views) and "/estimator/fake/notes/bias" not in \
        read_recording(rrd2)


class NotExcited(FakeFriction):
    """The full model whose Cx was never excited (the MPF's `cx_weight_max` below
    metrics.CX_EXCITED), as on snow-sine."""

    name = "cxfake"
    params = ("Cx", "Cf_y", "Cr_y")
    friction = None
    cx_weight_max = 0.12

    def step(self, t, u, y):
        est = super().step(t, u, y)
        from dataclasses import replace

        return replace(est, Cx=2e5, Cx_std=1e3)


def test_a_run_whose_metrics_say_cx_is_not_excited_says_so_on_the_cx_plot(fmu_paths, tmp_path):
    from tirefilter.metrics import CX_EXCITED

    scenario = load_scenario(_short_scenario(tmp_path, 1.0))
    rrd = tmp_path / "cx.rrd"
    run_scenario(scenario, estimator=NotExcited(), seed=0, recording=RecordingOptions(rrd=rrd, log_every=50))
    rec = read_recording(rrd)
    note = rec["/estimator/cxfake/notes/Cx"][0]["TextDocument:text"][0]
    assert "not excited" in note and "0.12" in note and f"{CX_EXCITED:g}" in note
    view = read_blueprints(rrd)[-1]["Cx [kN/unit slip]: NOT EXCITED, prior only"]
    assert view["names"]["/estimator/cxfake/stiffness/Cx"] == ["estimate: prior, not excited"]
    assert "Cx [kN/unit slip]" in read_blueprints(rrd)[0]  # the first blueprint comes before the run's metrics


def test_cx_excited_in_paper_sim_has_no_note(cosim_recording):
    _, rec, rrd = cosim_recording
    assert "/estimator/mpf/notes/Cx" not in rec and "Cx [kN/unit slip]" in read_blueprints(rrd)[-1]


def test_y_ranges_of_the_final_blueprint_come_from_the_settled_data(cosim_recording):
    from tirefilter.viz.rerun_log import STARTUP_S, robust_range

    r, _, rrd = cosim_recording
    views = read_blueprints(rrd)[-1]
    after = r["t"] >= r["t"][0] + STARTUP_S
    expected = robust_range(np.concatenate([r["vy"][after], r["true_vy"][after]]))
    assert views["vy [m/s]"]["range"] == pytest.approx(expected)
    beta = robust_range(np.degrees(np.concatenate([r["beta"][after], r["true_beta"][after]])))
    assert views["beta [deg]"]["range"] == pytest.approx(beta)
    assert views["ESS [particles]"]["range"] == pytest.approx((0.0, 1.05 * N))
    assert all(views[f"{p} [{u}]"]["range"] is not None for p, u in (("Cx", "kN/unit slip"), ("Cf_y", "kN/rad")))
    assert all(v["range"] is None for v in read_blueprints(rrd)[0].values() if isinstance(v, dict) and "range" in v)


def test_ess_is_drawn_with_n_and_the_resampling_threshold(cosim_recording):
    r, rec, rrd = cosim_recording
    _, n = series(rec, "/estimator/mpf/ess/particles")
    _, threshold = series(rec, "/estimator/mpf/ess/threshold")
    assert len(n) == len(threshold) == len(r["t"]) and np.all(n == N) and np.all(threshold == 0.5 * N)
    names = read_blueprints(rrd)[-1]["ESS [particles]"]["names"]
    assert names["/estimator/mpf/ess/particles"] == ["N (particles)"]
    assert names["/estimator/mpf/ess/threshold"] == ["resampling threshold"]


def test_particle_clouds_are_framed_named_and_coloured_on_a_fixed_weight_scale(cosim_recording):
    from tirefilter.viz.clouds import REACH, viridis, weight_colors, weight_position

    _, rec, rrd = cosim_recording
    for what, names in (("stiffness", ["Cx [kN/unit slip]", "Cf_y [kN/rad]", "Cr_y [kN/rad]"]),
                        ("state", ["vx [m/s]", "vy [m/s]", "yaw rate [rad/s]"])):
        rows = temporal(rec, f"/estimator/mpf/particles/{what}", "Points3D:positions")
        labels = temporal(rec, f"/estimator/mpf/particles/{what}_axes/labels", "Points3D:labels")
        assert len(labels) == len(rows)
        for row, lab in zip(rows[1:], labels[1:]):
            x = np.array(row["Points3D:positions"])
            shown = x * np.array(row["Transform3D:scale"]) + np.array(row["Transform3D:translation"])
            # the view's frame: the cloud centred with unit spread, whatever it does (a fixed camera frames it)
            np.testing.assert_allclose(shown.mean(axis=0), 0.0, atol=1e-3)  # float32 positions
            spread = x.std(axis=0) > 1e-3 * np.abs(x.mean(axis=0))  # else all copies of one particle (after resampling)
            np.testing.assert_allclose(shown.std(axis=0)[spread], 1.0, rtol=1e-3)
            text = lab["Points3D:labels"]
            assert all(n in text for n in names)
            # per axis (its tick labels, then its name): round values inside the frame's -+REACH
            spread = 1 / np.ravel(row["Transform3D:scale"])
            center = -np.ravel(row["Transform3D:translation"]) * spread
            ends = [text.index(n) for n in names]
            for a, (start, end) in enumerate(zip([-1] + ends[:-1], ends)):
                ticks = np.array([float(v) for v in text[start + 1:end]])
                assert len(ticks) >= 3
                assert np.all(np.abs(ticks - center[a]) <= REACH * spread[a] * (1 + 1e-4)), (names[a], ticks, center[a])
        scale = [x for x in rec[f"/estimator/mpf/particles/{what}_axes/weight_scale/labels"] if x["t"] is None][0]
        assert "1 = uniform" in scale["Points3D:labels"] and "weight x N" in scale["Points3D:labels"]
    if "stiffness means per particle" not in read_blueprints(rrd)[-1]:
        pytest.fail("no cloud view")
    # the colour of a particle is that of N w on a fixed log scale: after resampling all have the colour of 1
    uniform = weight_colors(np.full(7, -3.0))
    assert np.all(uniform == viridis(weight_position(1.0)))
    lw = np.log([8.0, 1.0, 1.0, 0.0001])
    c = weight_colors(lw)
    w = np.exp(lw) / np.exp(lw).sum()
    np.testing.assert_array_equal(c, viridis(weight_position(4 * w)))
    np.testing.assert_array_equal(weight_colors(np.log([2.0, 1.0, 1.0])), weight_colors(np.log([2.0, 1.0, 1.0]) + 5))


def test_nice_ticks_are_round_values_inside_the_range():
    from tirefilter.viz.clouds import nice_ticks

    ticks, decimals = nice_ticks(94.3, 105.7)  # 11.4 / 4 = 2.85: 2 apart
    np.testing.assert_allclose(ticks, [96.0, 98.0, 100.0, 102.0, 104.0])
    assert decimals == 0
    ticks, decimals = nice_ticks(-0.0213, 0.0189)
    np.testing.assert_allclose(ticks, [-0.02, -0.01, 0.0, 0.01])
    assert decimals == 2


def test_top_view_shows_the_whole_path_a_scale_and_the_sideslip(cosim_recording):
    from tirefilter.viz.blueprint import overview_eye
    from tirefilter.viz.rerun_log import ARROW_LENGTH, BETA_GAIN

    r, rec, rrd = cosim_recording
    # the true velocity's direction in the body frame, drawn at BETA_GAIN times beta to the heading
    # (a few degrees would not be seen), labelled with the gain and beta in degrees
    arrows = temporal(rec, "/vehicle/body/velocity", "Arrows3D:vectors")
    v = np.array([a["Arrows3D:vectors"][0] for a in arrows])
    assert len(v) == len(r["t"]) and BETA_GAIN == 10
    np.testing.assert_allclose(np.arctan2(v[:, 1], v[:, 0]), BETA_GAIN * r["true_beta"], atol=1e-5)
    np.testing.assert_allclose(np.hypot(v[:, 0], v[:, 1]), ARROW_LENGTH, rtol=1e-6)
    k = int(np.argmax(np.abs(r["true_beta"])))
    label = arrows[k]["Arrows3D:labels"][0]
    assert label.startswith("beta, drawn x10: ")
    assert f"{np.degrees(r['true_beta'][k]):+.1f}° true (black)" in label and "° est. (blue)" in label
    assert abs(np.degrees(BETA_GAIN * r["true_beta"][k])) > 10  # an angle one sees
    est = np.array([a["Arrows3D:vectors"][0] for a in temporal(rec, "/vehicle/body/velocity_estimate",
                                                                  "Arrows3D:vectors")])
    np.testing.assert_allclose(np.arctan2(est[:, 1], est[:, 0]), BETA_GAIN * r["beta"], atol=1e-5)
    # the overview's camera holds the whole path (Rerun's 3-D views: about 55 degrees high)
    views = read_blueprints(rrd)[-1]
    eye = views["path of the run [m]"]["eye"]
    x, y = r["true_x"], r["true_y"]
    bounds = (x.min(), x.max(), y.min(), y.max())
    position, target, up = overview_eye(bounds)
    assert eye["position"] == pytest.approx(position, rel=1e-5) and eye["look_target"] == pytest.approx(target)
    half_up_down = 0.5 * ((y.max() - y.min()) if up[1] else (x.max() - x.min()))
    half_across = 0.5 * ((x.max() - x.min()) if up[1] else (y.max() - y.min()))
    tan = math.tan(math.radians(27.5))
    assert half_up_down <= position[2] * tan and half_across <= position[2] * tan * 1.25
    # a scale bar of round length, labelled
    bar = [x for x in rec["/vehicle/scale"] if x["t"] is None][0]["LineStrips3D:strips"][0]
    label = [x for x in rec["/vehicle/scale/label"] if x["t"] is None][0]["Points3D:labels"][0]
    length = float(np.linalg.norm(np.subtract(bar[1], bar[0])))
    assert label == f"{length:g} m" and length >= 0.1 * max(x.max() - x.min(), y.max() - y.min())
    # the close-up follows the car (its position without heading) with a 10 m bar; it shows the time
    # cursor's arrows only (a visible time range drew every past arrow as a fan), the overview the trail to it
    close_up = views["car: heading vs velocity (beta)"]
    assert close_up["eye"]["tracking_entity"] == "/vehicle/position/frame" and "time_ranges" not in close_up
    assert views["path of the run [m]"].get("time_ranges")
    pos = np.array([p["Transform3D:translation"][0][:2] for p in temporal(rec, "/vehicle/position",
                                                                         "Transform3D:translation")])
    np.testing.assert_allclose(pos, np.column_stack([x, y]), rtol=1e-6, atol=1e-4)
    assert [x for x in rec["/vehicle/position/scale/label"] if x["t"] is None][0]["Points3D:labels"] == ["10 m"]
