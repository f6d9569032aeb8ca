"""The friction GP-SSM's benchmarks: tables on stdout, figures as PNG.

    PYTHONPATH=src .venv/bin/python benchmarks/bench_friction.py [--parts accuracy combined real cost]
        [--trials 20] [--combined-trials 10] [--particles 200] [--out benchmarks/figures] [--workers 2]
        [--band calibrated|posterior] [--option KEY=VALUE ...]

1. accuracy: friction-snow, N = 200, Ts = 40 ms, the paper's kernel (L = 30 deg, l = 2 deg,
   s_f = 500), tensor basis (the paper's, 10 x 10 of which the odd 50 are kept) and per-axle
   basis (10 odd functions per axle) on the same seeds: RMSE of mu_f, mu_r against the
   true Pacejka curve over the slip range visited so far (the *true* slip angles up to the
   snapshot; windows never come from the estimator) at 4, 20, 40, 50 s and the
   end, and the share of that range where the 90 % band (+-1.645 std) covers the truth, per
   snapshot and over all snapshots (every 2 s); a plot as the
   paper's Fig. 1 (trial 0). With the basis comparison (part 2): per-step cost side by side.
2. cost: median step time at N = 200 of tensor / axle with exact and rank-one statistics
   (one process, one core; `--cost-inputs` runs it on saved inputs where there is no FMU)
   and the rank-one variant's accuracy next to the exact one's.
3. combined: gpssm vs combined on snow and on dry asphalt (friction-snow with the
   dry-asphalt tire set): RMSE over time, the time from which both axles stay within 5%
   of the peak friction, and the 90 % band's coverage over all snapshots.
4. real: the MBDS race-track recording (lateral, v^X given): learned curves with bands (no
   truth), and the one-step-ahead prediction error of a^Y and yaw rate against the linear
   single-track Kalman filter with fixed stiffness.
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import tempfile
import time
import tomllib
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SNAPSHOTS = (4.0, 20.0, 40.0, 50.0)
FIXED_RANGE = 3.0 * math.pi / 180.0  # rad: the window of the "reach" time (combined vs gpssm)
Z90 = 1.645  # the 90 % band: +- this many std
DEG = math.pi / 180.0


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def snow_scenario(surface: str = "snow"):
    from tirefilter.scenarios import _load_pacejka, load_scenario

    sc = load_scenario("friction-snow")
    if surface == "snow":
        return sc
    p = _load_pacejka(Path(sc.file).parent / "tires" / f"{surface}.toml")
    return replace(sc, name=f"friction-{surface}", model=replace(sc.model, pacejka=p))


def truth_curve(sc, alpha):
    from tirefilter.vehicle.tires import pure_lateral_friction

    return pure_lateral_friction(sc.model.pacejka, alpha)


def run_trial(job: dict) -> dict:
    """One co-simulation with friction snapshots every 2 s; returns the metrics per snapshot."""
    from tirefilter.cosim.fmu import VehicleFMU
    from tirefilter.io.friction import read_friction, snapshot_blocks
    from tirefilter.io.results import result_columns
    from tirefilter.cosim.run import run_scenario
    from tirefilter.estimators import build_estimator

    sc = snow_scenario(job["surface"])
    if job.get("duration"):
        sc = replace(sc, duration=job["duration"])
    cfg = {"gpssm": dict(job["gpssm"], snapshot_every=2.0)}
    est = build_estimator(job["estimator"], sc, model="auto", particles=job["particles"], config=cfg)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "friction.csv"
        summary, rows = run_scenario(sc, estimator=est, seed=job["seed"], keep_rows=True, friction_csv=path)
        blocks = snapshot_blocks(read_friction(path))
    cols = dict(zip(result_columns(VehicleFMU().output_names), rows.T))
    peak = float(np.max(truth_curve(sc, np.linspace(0, 30 * DEG, 601))))
    out = {"t": [], "rmse_f": [], "rmse_r": [], "cov_f": [], "cov_r": [], "fix_f": [], "fix_r": [], "peak": peak,
           "median_step_us": summary.median_step_us, "diag": est.diagnostics(), "job": job, "curves": {},
           "vy_rmse": float(np.sqrt(np.mean((cols["vy"] - cols["true_vy"]) ** 2)))}
    for b in blocks:
        t = float(b["t"][0])
        seen = cols["t"] <= t + 1e-9
        out["t"].append(t)
        for axle in ("f", "r"):
            a_true = cols[f"true_alpha_{axle}"][seen]
            lo, hi = float(a_true.min()), float(a_true.max())
            m = (b["alpha"] >= lo) & (b["alpha"] <= hi)
            err = b[f"mu_{axle}"][m] - b[f"true_mu_{axle}"][m]
            out[f"rmse_{axle}"].append(float(np.sqrt(np.mean(err**2))) if m.any() else math.nan)
            inside = np.abs(err) <= Z90 * b[f"mu_{axle}_std"][m]
            out[f"cov_{axle}"].append(float(np.mean(inside)) if m.any() else math.nan)
            fix = np.abs(b["alpha"]) <= FIXED_RANGE + 1e-12  # a fixed window, visited or not
            out[f"fix_{axle}"].append(float(np.sqrt(np.mean((b[f"mu_{axle}"][fix] - b[f"true_mu_{axle}"][fix]) ** 2))))
        if job.get("keep_curves") and (any(abs(t - s) < 1e-6 for s in SNAPSHOTS) or b is blocks[-1]):
            out["curves"][t] = {k: v.copy() for k, v in b.items()} | {
                "visited": (float(cols["true_alpha_f"][seen].min()), float(cols["true_alpha_f"][seen].max()),
                            float(cols["true_alpha_r"][seen].min()), float(cols["true_alpha_r"][seen].max()))}
    if job.get("keep_curves"):
        out["prior"] = est.prior0(b["alpha"], b["alpha"])
        out["alpha_f_hist"] = cols["true_alpha_f"]
    return out


def _map(jobs, workers):
    if workers <= 1:
        return [run_trial(j) for j in jobs]
    with ProcessPoolExecutor(workers) as ex:
        return list(ex.map(run_trial, jobs))


def _all_cov(res, axle: str) -> float:
    """The 90 % band's coverage pooled over every snapshot of every trial (weighted alike)."""
    return float(np.nanmean(np.concatenate([np.asarray(r[f"cov_{axle}"], float) for r in res])))


def _at(res, t):
    i = int(np.argmin(np.abs(np.asarray(res["t"]) - t)))
    return i


def accuracy(args):
    print(f"\n== 1-2. friction-snow accuracy, {args.trials} trials, N = {args.particles}, Ts = 40 ms, "
          "L = 30 deg, l = 2 deg, s_f = 500 ==")
    results = {}
    for basis in args.bases:
        jobs = [dict(surface="snow", estimator="gpssm", particles=args.particles, seed=s,
                     gpssm=dict(args.gpssm, basis=basis, band=args.band),
                     keep_curves=(s == 0), duration=args.duration) for s in range(args.trials)]
        t0 = time.perf_counter()
        results[basis] = _map(jobs, args.workers)
        print(f"[{basis}: {time.perf_counter() - t0:.0f} s wall]")
    first = results[args.bases[0]]
    peak = first[0]["peak"]
    print(f"peak friction of the truth over [0, 30 deg]: {peak:.4f}; target RMSE <= 5% = {0.05 * peak:.4f}")
    print(f"{'basis':7s} {'t [s]':>6s} {'RMSE mu_f':>10s} {'RMSE mu_r':>10s} {'% peak f':>9s} {'% peak r':>9s} "
          f"{'cov f':>6s} {'cov r':>6s} {'met (trials)':>12s}")
    end = first[0]["t"][-1]
    for basis, res in results.items():
        for t in SNAPSHOTS + (end,):
            rf = np.array([r["rmse_f"][_at(r, t)] for r in res])
            rr = np.array([r["rmse_r"][_at(r, t)] for r in res])
            cf = np.array([r["cov_f"][_at(r, t)] for r in res])
            cr = np.array([r["cov_r"][_at(r, t)] for r in res])
            met = np.sum((rf <= 0.05 * peak) & (rr <= 0.05 * peak) & (cf >= 0.85) & (cr >= 0.85))
            print(f"{basis:7s} {t:6.0f} {np.mean(rf):10.4f} {np.mean(rr):10.4f} {100 * np.mean(rf) / peak:9.2f} "
                  f"{100 * np.mean(rr) / peak:9.2f} {np.mean(cf):6.2f} {np.mean(cr):6.2f} {met:5d}/{len(res)}")
        acc = np.sum([(r["rmse_f"][-1] <= 0.05 * peak) & (r["rmse_r"][-1] <= 0.05 * peak) for r in res])
        print(f"{basis:7s} 90 % band coverage over all snapshots (every 2 s) and trials: "
              f"f {_all_cov(res, 'f'):.3f}, r {_all_cov(res, 'r'):.3f} (target 0.85-0.95)")
        print(f"{basis:7s} end: RMSE target met (both axles) in {acc}/{len(res)} trials; median over trials of the "
              f"median step time {np.median([r['median_step_us'] for r in res]):.0f} us; v^Y RMSE "
              f"{np.mean([r['vy_rmse'] for r in res]):.3f} m/s; slip clipped "
              f"{sum(r['diag']['slip_clipped_samples'] for r in res)} particle samples")
    if not args.no_plots:
        for basis, res in results.items():
            fig1(res[0], args.out / f"friction_fig1_{basis}.png", basis)
        rmse_over_time({f"gpssm {b}": results[b] for b in results}, args.out / "friction_rmse_basis.png", peak,
                       "friction-snow: tensor vs per-axle basis")
    return results


def fig1(r, path: Path, label: str):
    plt = _plt()
    times = sorted(r["curves"])
    fig, axes = plt.subplots(3, len(times), figsize=(3.2 * len(times), 8), sharey="row")
    for j, t in enumerate(times):
        b = r["curves"][t]
        a = np.degrees(b["alpha"])
        for i, axle in enumerate(("f", "r")):
            ax = axes[i, j]
            mu, sd = b[f"mu_{axle}"], b[f"mu_{axle}_std"]
            ax.fill_between(a, mu - Z90 * sd, mu + Z90 * sd, color="0.8", label="90 % band")
            ax.plot(a, mu, "k", label="estimate")
            ax.plot(a, b[f"true_mu_{axle}"], "r--", label="truth")
            ax.plot(a, r["prior"][i], "k-.", lw=0.8, label="initial estimate")
            lo, hi = b["visited"][2 * i: 2 * i + 2]
            for v in (lo, hi):
                ax.axvline(np.degrees(v), color="g", ls="--", lw=0.8)
            ax.set_xlim(-20, 20)
            ax.set_ylim(-0.5, 0.5)
            ax.set_title(f"{'front' if axle == 'f' else 'rear'}, t = {t:g} s", fontsize=9)
            if j == 0:
                ax.set_ylabel(f"mu_{axle}")
        seen = r["alpha_f_hist"][: int(round(t / 0.04)) + 1]
        axes[2, j].hist(np.degrees(seen), bins=60, color="tab:blue")
        axes[2, j].set_xlim(-20, 20)
        axes[2, j].set_xlabel("alpha_f [deg] (true, accumulated)")
    axes[0, 0].legend(fontsize=7, loc="upper left")
    fig.suptitle(f"friction-snow, gpssm ({label} basis), trial 0: as the paper's Fig. 1")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    print(f"figure: {path}")


def rmse_over_time(groups: dict, path: Path, peak: float, title: str, key: str = "rmse"):
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), sharey=True)
    for (label, res), color in zip(groups.items(), ("tab:blue", "tab:red", "tab:green", "tab:orange")):
        t = np.asarray(res[0]["t"])
        for ax, axle in zip(axes, ("f", "r")):
            R = np.array([r[f"{key}_{axle}"] for r in res]) / peak * 100
            ax.plot(t, np.median(R, 0), color=color, label=label)
            ax.fill_between(t, np.percentile(R, 10, 0), np.percentile(R, 90, 0), color=color, alpha=0.2)
    for ax, axle in zip(axes, ("front", "rear")):
        ax.axhline(5, color="k", ls=":", lw=0.8)
        ax.set_yscale("log")
        ax.set_xlabel("t [s]")
        where = "the visited range" if key == "rmse" else "|alpha| <= 3 deg"
        ax.set_title(f"{axle}: RMSE over {where}, % of peak (median, 10-90%)", fontsize=9)
    axes[0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    print(f"figure: {path}")


def reach_time(r, peak, key="rmse"):
    """First snapshot time from which both axles stay within 5% of the peak (inf: never):
    key "rmse" over the range visited so far, "fix" over |alpha| <= 3 deg."""
    ok = (np.asarray(r[f"{key}_f"]) <= 0.05 * peak) & (np.asarray(r[f"{key}_r"]) <= 0.05 * peak)
    t = np.asarray(r["t"])
    for i in range(len(t)):
        if ok[i:].all():
            return float(t[i])
    return math.inf


def combined(args):
    print(f"\n== 3. gpssm vs combined ({args.combined_trials} trials, N = {args.particles}, "
          f"{args.combined_basis} basis) ==")
    print("reach: first snapshot (every 2 s) from which the RMSE of both axles stays <= 5% of the peak; 'visited' over "
          "the true slip range seen so far, '|a|<=3' over the fixed window |alpha| <= 3 deg (visited or not)")
    print(f"{'surface':12s} {'estimator':9s} {'reach visited':>13s} {'reach |a|<=3':>13s} {'never':>6s} "
          f"{'end RMSE f %':>13s} {'end RMSE r %':>13s} {'handover [s]':>13s} {'step us':>8s} {'cov90 f':>8s} "
          f"{'cov90 r':>8s}")
    out = {}
    for surface in ("snow", "dry-asphalt"):
        groups = {}
        for name in ("gpssm", "combined"):
            jobs = [dict(surface=surface, estimator=name, particles=args.particles, seed=100 + s,
                         gpssm=dict(args.gpssm, basis=args.combined_basis, band=args.band),
                         duration=args.duration)
                    for s in range(args.combined_trials)]
            res = _map(jobs, args.workers)
            peak = res[0]["peak"]
            reach = np.array([reach_time(r, peak) for r in res])
            reach_fix = np.array([reach_time(r, peak, "fix") for r in res])
            hand = [r["diag"]["handover_time"] for r in res if r["diag"]["handover_time"] is not None]
            print(f"{surface:12s} {name:9s} {np.median(reach):13.1f} {np.median(reach_fix):13.1f} "
                  f"{np.sum(~np.isfinite(reach_fix)):6d} "
                  f"{100 * np.mean([r['rmse_f'][-1] for r in res]) / peak:13.2f} "
                  f"{100 * np.mean([r['rmse_r'][-1] for r in res]) / peak:13.2f} "
                  f"{(np.median(hand) if hand else math.nan):13.1f} "
                  f"{np.median([r['median_step_us'] for r in res]):8.0f} {_all_cov(res, 'f'):8.3f} "
                  f"{_all_cov(res, 'r'):8.3f}")
            groups[name] = res
        out[surface] = groups
        if not args.no_plots:
            rmse_over_time(groups, args.out / f"friction_combined_{surface}.png", groups["gpssm"][0]["peak"],
                           f"friction-{surface}: gpssm vs combined ({args.combined_basis} basis)", key="fix")
    return out


def record_inputs(duration: float = 20.0) -> dict:
    """The estimator's inputs and measurements of a friction-snow co-simulation (seed 0)."""
    from tirefilter.cosim.fmu import VehicleFMU
    from tirefilter.io.results import result_columns
    from tirefilter.cosim.run import run_scenario

    sc = replace(snow_scenario(), duration=duration)
    _, rows = run_scenario(sc, seed=0, keep_rows=True)
    c = dict(zip(result_columns(VehicleFMU().output_names), rows.T))
    return {"t": c["t"], "delta": c["meas_delta"], "vx": c["true_vx"], "ay": c["meas_ay"],
            "yaw_rate": c["meas_yaw_rate"]}


def time_steps(basis: str, stats: str, particles: int, inputs: dict, symmetry: str = "odd") -> tuple[float, float]:
    """Median wall time and median CPU time (this process) [us] of step() over the inputs
    after 10 warm-up steps. On a shared, loaded machine the wall time includes waiting
    for a core; the CPU time does not."""
    from tirefilter.estimators.base import Inputs, Measurement
    from tirefilter.estimators.gpssm.filter import FrictionGPSSM, GPSSMConfig

    sc = snow_scenario()
    p = sc.model.pacejka
    est = FrictionGPSSM(sc.vehicle, GPSSMConfig(particles=particles, basis=basis, stats=stats, prior_peak=0.05,
                                                symmetry=symmetry),
                        tire_shape=(p.B_y, p.C_y, p.E_y))
    est.reset(np.random.default_rng(0))
    times, cpu = [], []
    for k in range(len(inputs["t"])):
        u = Inputs(delta=float(inputs["delta"][k]), vx=float(inputs["vx"][k]))
        y = Measurement(ay=float(inputs["ay"][k]), yaw_rate=float(inputs["yaw_rate"][k]))
        t0, c0 = time.perf_counter(), time.process_time()
        est.step(float(inputs["t"][k]), u, y)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return float(np.median(times[10:]) * 1e6), float(np.median(cpu[10:]) * 1e6)


def cost(args):
    """Per-step cost at N (default 200) per basis and statistics variant, and (with the FMU)
    the rank-one variant's accuracy next to the exact one's."""
    if args.cost_inputs:
        inputs = dict(np.load(args.cost_inputs))
    else:
        inputs = record_inputs()
        if args.save_cost_inputs:
            np.savez(args.save_cost_inputs, **inputs)
            print(f"inputs for the cost part: {args.save_cost_inputs}")
    print(f"\n== 2b. per-step cost at N = {args.particles} (20 s of friction-snow inputs, median of step() after "
          "10 warm-up steps, one process) ==")
    import os

    print(f"load average before: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"{'basis':7s} {'stats':6s} {'symmetry':8s} {'functions':>9s} {'wall us':>8s} {'CPU us':>8s}")
    for basis, symmetry, size in (("tensor", "none", 100), ("tensor", "odd", 50), ("axle", "odd", 20)):
        for stats in ("exact", "rank1"):
            us, cpu = time_steps(basis, stats, args.particles, inputs, symmetry)
            print(f"{basis:7s} {stats:6s} {symmetry:8s} {size:9d} {us:8.0f} {cpu:8.0f}")
    print(f"load average after: {os.getloadavg()[0]:.1f}")
    if args.cost_inputs:
        return
    print(f"\naccuracy of the statistics variants (friction-snow, {args.variant_trials} trials, 80 s, "
          f"N = {args.particles}):")
    print(f"{'basis':7s} {'stats':6s} {'end RMSE f %':>13s} {'end RMSE r %':>13s}")
    for basis in ("tensor", "axle"):
        for stats in ("exact", "rank1"):
            jobs = [dict(surface="snow", estimator="gpssm", particles=args.particles, seed=s,
                         gpssm={"basis": basis, "stats": stats}, duration=args.duration)
                    for s in range(args.variant_trials)]
            res = _map(jobs, args.workers)
            peak = res[0]["peak"]
            print(f"{basis:7s} {stats:6s} {100 * np.mean([r['rmse_f'][-1] for r in res]) / peak:13.2f} "
                  f"{100 * np.mean([r['rmse_r'][-1] for r in res]) / peak:13.2f}")


def real(args):
    from tirefilter.estimators import build_log_estimator
    from tirefilter.estimators.linear_kf import KFConfig, LinearKF
    from tirefilter.replay import read_log, replay_log
    from tirefilter.vehicle.params import load_vehicle

    example = REPO / "examples" / "mbds-sideslip"
    spec = importlib.util.spec_from_file_location("mbds_convert", example / "convert.py")
    convert = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(convert)
    if not convert.DATA.exists():
        print(f"\n== 4. real recording: skipped, {convert.DATA} is not there ==")
        return
    vehicle = load_vehicle(example / "vehicle.toml")
    with tempfile.TemporaryDirectory() as tmp:
        log = read_log(convert.convert(out=Path(tmp) / "log.csv", start=args.real_start, end=args.real_end), vehicle)
    print(f"\n== 4. real recording: {log.rows} samples over {log.duration:.0f} s, N = {args.particles}, "
          f"{args.combined_basis} basis ==")
    ay, r_m, vx, delta = (log.signal(s) for s in ("ay", "yaw_rate", "vx", "delta"))
    ok = np.isfinite(ay) & np.isfinite(r_m)
    rows = []
    curves = {}
    for name in ("gpssm", "combined"):
        est = build_log_estimator(name, vehicle, log.t, {s: log.signals[s] for s in log.available}, model="lateral",
                                  particles=args.particles, config={"gpssm": {"basis": args.combined_basis}},
                                  source=log.path)
        pred = np.full((log.rows, 2), np.nan)
        orig = est.step

        def step(t, u, y, _k=[0], _est=est, _orig=orig, _pred=pred):
            e = _orig(t, u, y)
            _pred[_k[0]] = _est.prediction
            _k[0] += 1
            return e

        est.step = step
        summary, _ = replay_log(log, estimator=est, seed=0)
        curves[name] = est.friction()
        rows.append((name, pred, summary.median_step_us, est.diagnostics()))
    for label, (cf, cr) in (("kf, publishers' stiffness", (7.0e4, 1.2e5)),
                            ("kf, least-squares stiffness", (5.5e4, 7.1e4))):
        kf = LinearKF(vehicle, KFConfig(Cf_y=cf, Cr_y=cr))
        pred = np.full((log.rows, 2), np.nan)
        t0 = time.perf_counter()
        for k in range(log.rows):
            d = delta[k] if math.isfinite(delta[k]) else kf.delta_last
            if kf.t_prev is not None:
                kf.predict(*kf.u_prev, log.t[k] - kf.t_prev)
            _, _, C, dd = kf._model(vx[k], d)
            pred[k] = C @ kf.x + dd
            kf.update(vx[k], d, np.array([ay[k], r_m[k]]))
            kf.t_prev, kf.u_prev, kf.delta_last = log.t[k], (vx[k], d), d
        rows.append((label, pred, (time.perf_counter() - t0) / log.rows * 1e6, None))
    hi = ok & (np.abs(ay) >= 6.0)
    print(f"{'model':30s} {'a^Y RMSE':>9s} {'r RMSE':>9s} {'a^Y |ay|>=6':>12s} {'r |ay|>=6':>10s} {'step us':>8s}")
    for label, pred, us, diag in rows:
        m = ok & np.isfinite(pred).all(1)
        e_a, e_r = pred[:, 0] - ay, pred[:, 1] - r_m
        f = lambda e, mask: math.sqrt(np.mean(e[mask] ** 2))  # noqa: E731
        print(f"{label:30s} {f(e_a, m):9.3f} {f(e_r, m):9.4f} {f(e_a, m & hi):12.3f} {f(e_r, m & hi):10.4f} {us:8.0f}")
        if diag:
            print(f"    {label}: slip clipped {diag['slip_clipped_samples']} of {diag['particle_slip_evaluations']}, "
                  f"handover {diag['handover_time']}")
    print("(a^Y in m/s^2, r in rad/s: one-step-ahead prediction minus measurement; the IMU noise is "
          f"{vehicle.sigma_ay} m/s^2 and {vehicle.sigma_yaw_rate} rad/s; |ay| >= 6 m/s^2 on {100 * hi.mean():.0f}%)")
    if not args.no_plots:
        plt = _plt()
        fig, axes = plt.subplots(1, 2, figsize=(10, 3.8), sharey=True)
        for name, color in (("gpssm", "tab:blue"), ("combined", "tab:red")):
            fc = curves[name]
            a = np.degrees(fc.alpha)
            for ax, mu, sd, vis in ((axes[0], fc.mu_f, fc.mu_f_std, fc.visited[:2]),
                                    (axes[1], fc.mu_r, fc.mu_r_std, fc.visited[2:])):
                ax.fill_between(a, mu - Z90 * sd, mu + Z90 * sd, color=color, alpha=0.25)
                ax.plot(a, mu, color=color, label=name)
                for v in vis:
                    ax.axvline(np.degrees(v), color=color, ls="--", lw=0.7)
        for ax, axle in zip(axes, ("front", "rear")):
            ax.set_xlim(-12, 12)
            ax.set_xlabel("alpha [deg]")
            ax.set_title(f"{axle}: learned mu at the end, 90 % band, visited range (dashed)", fontsize=9)
        axes[0].set_ylabel("mu = F^y / F^z (static load)")
        axes[0].legend()
        fig.suptitle("MBDS race-track recording: learned friction curves (no truth exists)")
        fig.tight_layout()
        path = args.out / "friction_real.png"
        fig.savefig(path, dpi=80)
        plt.close(fig)
        print(f"figure: {path}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--parts", nargs="+", default=["accuracy", "cost", "combined", "real"],
                    choices=("accuracy", "cost", "combined", "real"))
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--bases", nargs="+", default=["tensor", "axle"], choices=("tensor", "axle"),
                    help="bases of the accuracy part")
    ap.add_argument("--combined-trials", type=int, default=10)
    ap.add_argument("--combined-basis", default="axle", choices=("tensor", "axle"))
    ap.add_argument("--band", default="calibrated", choices=("calibrated", "posterior"),
                    help="the band of the learned curve ([gpssm] band; posterior: eq. (30) alone)")
    ap.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                    help="a [gpssm] option (TOML value) for the accuracy and combined parts, e.g. force_hold=\"zero\"")
    ap.add_argument("--particles", type=int, default=200)
    ap.add_argument("--duration", type=float, help="shorten the co-simulations to this many seconds")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--variant-trials", type=int, default=5, help="trials per statistics variant (cost part)")
    ap.add_argument("--cost-inputs", type=Path, help="cost part only, on these saved inputs (no FMU needed)")
    ap.add_argument("--save-cost-inputs", type=Path, help="save the cost part's inputs (.npz)")
    ap.add_argument("--real-start", type=float)
    ap.add_argument("--real-end", type=float)
    ap.add_argument("--out", type=Path, default=REPO / "benchmarks" / "figures")
    ap.add_argument("--no-plots", action="store_true")
    args = ap.parse_args()
    args.gpssm = tomllib.loads("\n".join(args.option))
    if args.gpssm:
        print(f"[gpssm] options: {args.gpssm}")
    if "accuracy" in args.parts:
        accuracy(args)
    if "cost" in args.parts:
        cost(args)
    if "combined" in args.parts:
        combined(args)
    if "real" in args.parts:
        real(args)


if __name__ == "__main__":
    main()
