"""The stiffness study's figures, after the paper's (matplotlib, written as PNG).

Stiffness is shown normalised by the true surface mean of the first surface (as the
paper normalises by ground truth), so 1 is right before the surface change.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from tirefilter.study.montecarlo import PARAMS

COLORS = {"mpf": "tab:red", "augpf": "tab:cyan", "rls": "tab:blue", "ekf": "tab:green", "kf": "tab:gray"}
LABELS = {"mpf": "MPF (Algorithm 1)", "augpf": "AUGPF", "rls": "RLS", "ekf": "EKF", "kf": "KF (fixed stiffness)"}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    _plt().close(fig)
    return path


def _params(series: dict) -> list[str]:
    return [p for p in PARAMS if p in series and np.any(np.isfinite(series[p]))]


def _norm(series: dict, p: str) -> float:
    return float(series[f"true_{p}_mean"][0])


def one_trial(ax_row, series: dict, est: str, *, band: bool = True, sigma: bool = True, truth: bool = True) -> None:
    """Fig. 4 / 11 style: estimate (+- 2 posterior std of the mean) and its spread."""
    t = series["t"]
    for ax, p in zip(ax_row, _params(series)):
        c = _norm(series, p)
        if truth:
            ax.plot(t, series[f"true_{p}_mean"] / c, "k--", lw=1, label="true surface mean")
        ax.plot(t, series[p] / c, color=COLORS.get(est, "k"), lw=1.2, label=LABELS.get(est, est))
        if band and f"{p}_std" in series:
            s = series[f"{p}_std"] / c
            ax.fill_between(t, series[p] / c - 2 * s, series[p] / c + 2 * s, color=COLORS.get(est, "k"), alpha=0.2,
                            lw=0)
        if sigma and f"{p}_sigma" in series and np.any(np.isfinite(series[f"{p}_sigma"])):
            ax.plot(t, series[f"{p}_sigma"] / c, color="tab:olive", lw=1, label="spread sigma (27b)")
        ax.set_ylabel(f"{p} / truth")
        ax.grid(alpha=0.3)


def accuracy_plots(runs: dict, out: Path, opts) -> list[Path]:
    plt = _plt()
    paths = []
    trial0 = {est: run.series(min(run.metrics)) for (_, est, _), run in runs.items() if run.metrics}
    trial0 = {k: v for k, v in trial0.items() if v}
    if trial0:
        params = max((_params(s) for s in trial0.values()), key=len)
        fig, axes = plt.subplots(len(params), 1, figsize=(8, 2.4 * len(params)), sharex=True, squeeze=False)
        for j, (est, s) in enumerate(trial0.items()):
            one_trial([axes[params.index(p), 0] for p in _params(s)], s, est, sigma=est == "mpf", truth=j == 0)
        axes[0, 0].legend(fontsize=7, loc="upper right")
        axes[-1, 0].set_xlabel("t [s]")
        fig.suptitle("Fig. 4: one trial (trial 0), estimate +- 2 std of the mean")
        paths.append(_save(fig, out / "fig4_one_trial.png"))
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.5))
    for (_, est, _), run in runs.items():
        ok = [m["Cf_y"] for m in run.ok() if "Cf_y" in m]
        if not ok:
            continue
        a1.hist([m["mean"] for m in ok], bins=20, alpha=0.5, color=COLORS.get(est), label=LABELS.get(est, est))
        se = [m["sigma_err"] for m in ok if m.get("sigma_err") is not None and math.isfinite(m["sigma_err"])]
        if se:
            a2.hist(se, bins=20, alpha=0.5, color=COLORS.get(est), label=LABELS.get(est, est))
    a1.set_xlabel("time-averaged error of the Cf_y estimate [%]")
    a2.set_xlabel("time-averaged error of the Cf_y spread sigma [points of the mean]")
    for a in (a1, a2):
        a.set_ylabel("trials")
        a.legend(fontsize=7)
    fig.suptitle("Fig. 6: mean and standard-deviation error, front lateral stiffness")
    paths.append(_save(fig, out / "fig6_histograms.png"))
    return paths


def particles_plots(runs: dict, out: Path, opts) -> list[Path]:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4))
    for est in sorted({k[1] for k in runs}):
        pts = sorted((k[2], run) for k, run in runs.items() if k[1] == est)
        n = [p[0] for p in pts]
        rmse = [np.array([m["vy_rmse"] for m in run.ok()]) for _, run in pts]
        mean = [x.mean() if x.size else math.nan for x in rmse]
        err = [x.std(ddof=1) / math.sqrt(x.size) if x.size > 1 else 0.0 for x in rmse]
        ax.errorbar(n, mean, yerr=err, marker="o", capsize=3, color=COLORS.get(est), label=LABELS.get(est, est))
    ax.set_xscale("log")
    ax.set_xlabel("particles N")
    ax.set_ylabel("time-averaged v^Y RMSE [m/s]")
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    ax.set_title("Fig. 5: v^Y RMSE against N (mean over trials +- s.e.)")
    return [_save(fig, out / "fig5_vy_rmse.png")]


def comparison_plots(runs: dict, out: Path, opts) -> list[Path]:
    from tirefilter.scenarios import load_scenario
    from tirefilter.study.stiffness import steady_errors

    plt = _plt()
    paths = []
    for scenario in sorted({k[0] for k in runs}):
        sc = load_scenario(scenario)
        mine = {k[1]: run for k, run in runs.items() if k[0] == scenario}
        mpf = mine.get("mpf")
        tag = scenario.replace("-", "_")
        if mpf is not None and mpf.metrics:
            all_series = [s for s in (mpf.series(i) for i in sorted(mpf.metrics)) if s]
            params = _params(all_series[0]) if all_series else []
            if params:
                # Figs. 7 and 8: every trial overlaid, and the average over trials
                fig, axes = plt.subplots(len(params) + 1, 2, figsize=(11, 2.3 * (len(params) + 1)), sharex=True,
                                         squeeze=False)
                for s in all_series:
                    for j, p in enumerate(params):
                        c = _norm(s, p)
                        axes[j, 0].plot(s["t"], s[p] / c, "k", lw=0.5, alpha=0.4)
                        axes[j, 0].plot(s["t"], s[f"{p}_sigma"] / c, color="0.6", lw=0.5, alpha=0.4)
                s0 = all_series[0]
                for j, p in enumerate(params):
                    c = _norm(s0, p)
                    stack = np.array([s[p] / _norm(s, p) for s in all_series if s[p].shape == s0[p].shape])
                    sig = np.array([s[f"{p}_sigma"] / _norm(s, p) for s in all_series if s[p].shape == s0[p].shape])
                    axes[j, 1].plot(s0["t"], np.nanmean(stack, 0), "k", lw=1.2, label="mean estimate")
                    axes[j, 1].plot(s0["t"], np.nanmean(sig, 0), color="0.5", lw=1, label="mean spread sigma")
                    for col in (0, 1):
                        axes[j, col].plot(s0["t"], s0[f"true_{p}_mean"] / c, "k--", lw=1, label="truth")
                        axes[j, col].set_ylabel(f"{p} / truth")
                        axes[j, col].grid(alpha=0.3)
                for col in (0, 1):
                    axes[-1, col].plot(s0["t"], s0["yaw_rate"], "k", lw=1, label="estimated")
                    axes[-1, col].plot(s0["t"], s0["meas_yaw_rate"], "k:", lw=0.8, label="measured")
                    axes[-1, col].set_ylabel("yaw rate [rad/s]")
                    axes[-1, col].set_xlabel("t [s]")
                axes[0, 0].set_title(f"Fig. 7: all {len(all_series)} MPF trials")
                axes[0, 1].set_title("Fig. 8: average over trials")
                axes[0, 1].legend(fontsize=7)
                paths.append(_save(fig, out / f"fig7_8_{tag}.png"))
        if "ekf" in mine and mpf is not None:
            # Fig. 9: EKF against the MPF on two trials
            idx = sorted(set(mine["ekf"].metrics) & set(mpf.metrics))[:2]
            if idx:
                fig, axes = plt.subplots(2, len(idx), figsize=(5 * len(idx), 5), sharex=True, squeeze=False)
                for col, i in enumerate(idx):
                    se, sm = mine["ekf"].series(i), mpf.series(i)
                    for row, p in enumerate(("Cf_y", "Cr_y")):
                        c = _norm(sm, p)
                        axes[row, col].plot(sm["t"], sm[f"true_{p}_mean"] / c, "k--", lw=1, label="truth")
                        axes[row, col].plot(sm["t"], sm[p] / c, "k", lw=1.2, label="MPF")
                        axes[row, col].plot(se["t"], se[p] / c, "k-.", lw=1, label="EKF")
                        axes[row, col].set_ylabel(f"{p} / truth")
                        axes[row, col].grid(alpha=0.3)
                    axes[0, col].set_title(f"{scenario}, trial {i}")
                axes[0, 0].legend(fontsize=7)
                fig.suptitle("Fig. 9: EKF against the MPF")
                paths.append(_save(fig, out / f"fig9_{tag}_ekf.png"))
        if mpf is not None and mpf.metrics:
            # Fig. 11: one trial with its band and the steer angle; Fig. 12: error histogram
            s = mpf.series(min(mpf.metrics))
            params = _params(s)
            fig, axes = plt.subplots(len(params) + 1, 1, figsize=(8, 2.3 * (len(params) + 1)), sharex=True)
            one_trial(axes[:-1], s, "mpf")
            axes[-1].plot(s["t"], s["true_delta"], "k", lw=1)
            axes[-1].set_ylabel("steer delta [rad]")
            axes[-1].set_xlabel("t [s]")
            axes[0].legend(fontsize=7)
            fig.suptitle(f"Fig. 11: one MPF trial on {scenario}")
            paths.append(_save(fig, out / f"fig11_{tag}_one_trial.png"))
            fig, ax = plt.subplots(figsize=(6, 4))
            for est, run in mine.items():
                errs = [steady_errors(x, sc, "Cf_y") for x in (run.series(i) for i in sorted(run.metrics)) if x]
                e = np.concatenate(errs) if errs else np.array([])
                e = e[np.isfinite(e)]
                if e.size:
                    ax.hist(e, bins=60, density=True, alpha=0.45, color=COLORS.get(est),
                            label=f"{LABELS.get(est, est)}: mean {e.mean():+.2f}%, std {e.std():.2f}%")
                    if est == "mpf":
                        g = np.linspace(e.min(), e.max(), 200)
                        ax.plot(g, np.exp(-0.5 * ((g - e.mean()) / e.std()) ** 2) / (e.std() * math.sqrt(2 * math.pi)),
                                "k", lw=1)
            ax.set_xlabel("steady-state error of Cf_y [%] (every sample of every trial)")
            ax.set_ylabel("density")
            ax.legend(fontsize=7)
            ax.set_title(f"Fig. 12: {scenario}, Gaussian of the MPF's mean and std in black")
            paths.append(_save(fig, out / f"fig12_{tag}_histogram.png"))
    return paths


def cost_plot(table: dict, estimators, particles, out: Path) -> Path:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4))
    for est in estimators:
        pts = [(n, table[(est, n)]) for n in particles if table.get((est, n))]
        if len(pts) == 1:
            ax.axhline(pts[0][1], color=COLORS.get(est), ls=":", label=f"{LABELS.get(est, est)} (no particles)")
        elif pts:
            ax.plot(*zip(*pts), marker="o", color=COLORS.get(est), label=LABELS.get(est, est))
    ref = [(n, table[("mpf", n)]) for n in particles if table.get(("mpf", n))]
    if ref:
        n_max, c_max = ref[-1]
        ax.plot(particles, [c_max * n / n_max for n in particles], "k--", lw=0.8, label="O(N)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("particles N")
    ax.set_ylabel("median step [us]")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    ax.set_title("Fig. 14: cost per step (one core)")
    return _save(fig, out / "fig14_cost.png")


PART_PLOTS = {"accuracy": accuracy_plots, "particles": particles_plots, "comparison": comparison_plots}
