"""The Monte-Carlo engine and `tirefilter bench stiffness` (short trials, few particles)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tirefilter.cli import main
from tirefilter.cosim.fmu import VehicleFMU
from tirefilter.io.results import read_results
from tirefilter.cosim.run import run_scenario
from tirefilter.errors import ConfigError
from tirefilter.estimators import build_estimator
from tirefilter.study.montecarlo import StudyRun, TrialSpec, run_study, study_scenario, trial_metrics, trial_seeds

SPEC = TrialSpec("paper-sim", "mpf", particles=40, duration=7.0)


def test_trial_seeds_come_from_one_seed_sequence():
    seeds = trial_seeds(0, 5)
    assert len(set(seeds)) == 5
    assert trial_seeds(0, 3) == seeds[:3]  # more trials extend the same list
    assert trial_seeds(1, 3) != seeds[:3]


def test_a_trial_is_reproduced_by_tirefilter_run_with_its_seed(tmp_path):
    run = run_study(SPEC, 2, tmp_path / "s", study_seed=4, workers=1)
    m = run.metrics[1]
    assert m["status"] == "ok" and m["seed"] == trial_seeds(4, 2)[1]
    scenario = study_scenario(SPEC)
    csv = tmp_path / "r.csv"
    run_scenario(scenario, estimator=build_estimator("mpf", scenario, model="auto", particles=40, config={}),
                 seed=m["seed"], results_csv=csv)
    again = trial_metrics(read_results(csv), scenario)
    assert again["vy_rmse"] == pytest.approx(m["vy_rmse"], rel=1e-9)
    assert again["Cf_y"]["mean"] == pytest.approx(m["Cf_y"]["mean"], rel=1e-9)
    series = run.series(1)
    assert series["t"].size == int(7.0 * 100 / SPEC.decimate) + 1
    assert np.all(np.isfinite(series["Cf_y"]))


def test_worker_pool_equals_one_process(tmp_path):
    one = run_study(SPEC, 3, tmp_path / "one", workers=1)
    pool = run_study(SPEC, 3, tmp_path / "pool", workers=2)
    for i in range(3):
        assert pool.metrics[i]["seed"] == one.metrics[i]["seed"]
        assert pool.metrics[i]["vy_rmse"] == one.metrics[i]["vy_rmse"]
        assert json.dumps(pool.metrics[i]["Cr_y"]) == json.dumps(one.metrics[i]["Cr_y"])


def test_finished_trials_are_kept_and_not_run_again(tmp_path):
    d = tmp_path / "s"
    run_study(SPEC, 2, d, workers=1)
    first = (d / "metrics.jsonl").read_text()
    run = run_study(SPEC, 3, d, workers=1)
    lines = (d / "metrics.jsonl").read_text().splitlines()
    assert (d / "metrics.jsonl").read_text().startswith(first)
    assert len(lines) == 3 and sorted(json.loads(x)["trial"] for x in lines) == [0, 1, 2]
    assert len(StudyRun(d, SPEC, 0).ok()) == 3 == len(run.ok())
    with pytest.raises(ConfigError, match="another configuration"):
        run_study(TrialSpec("paper-sim", "mpf", particles=41, duration=7.0), 1, d, workers=1)


def test_a_failing_trial_is_recorded_and_the_study_goes_on(tmp_path, monkeypatch):
    import tirefilter.estimators.mpf as mpf

    real = mpf.StiffnessMPF.step

    def step(self, t, u, y):
        if t >= 3.0 and self.cfg.particles == 40:
            raise FloatingPointError("diverged at t = 3 s")
        return real(self, t, u, y)

    monkeypatch.setattr(mpf.StiffnessMPF, "step", step)
    run = run_study(SPEC, 2, tmp_path / "s", workers=1)
    assert [run.metrics[i]["status"] for i in (0, 1)] == ["failed", "failed"]
    assert "diverged at t = 3 s" in run.metrics[0]["error"]
    assert run.ok() == []


def test_fmu_is_reset_between_trials(tmp_path):
    """Two trials on one FMU equal the same trials on fresh FMUs."""
    from tirefilter.study.montecarlo import run_trial

    with VehicleFMU() as fmu:
        shared = [run_trial(SPEC, i, s, fmu=fmu).metrics for i, s in enumerate(trial_seeds(0, 2))]
    for i, s in enumerate(trial_seeds(0, 2)):
        with VehicleFMU() as fmu:
            assert run_trial(SPEC, i, s, fmu=fmu).metrics["vy_rmse"] == shared[i]["vy_rmse"]


def test_bench_stiffness_command_writes_tables_and_plots(tmp_path, capsys):
    out = tmp_path / "bench"
    rc = main(["bench", "stiffness", "--out", str(out), "--part", "accuracy", "particles", "cost", "--trials", "2",
               "--duration", "7", "--particles", "30", "60", "--estimators", "mpf", "kf", "--workers", "1", "--quiet"])
    assert rc == 0
    text = capsys.readouterr().out
    report = (out / "report.md").read_text()
    assert "| mpf | 30 | Cf_y | 2 |" in report and "| kf | - | Cr_y | 2 |" in report
    assert "| 60 | - |" in report  # v^Y table: kf has no particles
    assert "| mpf |" in report.split("## cost")[1]
    for fig in ("fig4_one_trial.png", "fig5_vy_rmse.png", "fig6_histograms.png", "fig14_cost.png"):
        assert (out / fig).stat().st_size > 10_000, fig
    assert "report:" in text
    assert main(["bench", "stiffness", "--out", str(out), "--estimators", "nope"]) == 1
    assert "unknown estimator" in capsys.readouterr().err


def test_bench_stiffness_config_reaches_every_trial(tmp_path, capsys):
    """`--config` gives the trials its estimator tables: recorded in the spec, used by the
    filter (a different result from the defaults on the same seed), and a folder of one
    configuration refuses another."""
    cfg = tmp_path / "paper.toml"
    cfg.write_text('[mpf]\nslip_hold = "start"\nundriven_stiffness = "nominal"\n')
    args = ["bench", "stiffness", "--part", "accuracy", "--trials", "1", "--duration", "3", "--particles", "30",
            "--estimators", "mpf", "--workers", "1", "--quiet", "--no-plots"]
    assert main(args + ["--out", str(tmp_path / "paper"), "--config", str(cfg)]) == 0
    assert main(args + ["--out", str(tmp_path / "default")]) == 0
    spec = json.loads((tmp_path / "paper/accuracy/paper-sim/mpf-N30-3s/spec.json").read_text())
    assert spec["spec"]["config"] == {"mpf": {"slip_hold": "start", "undriven_stiffness": "nominal"}}
    runs = [np.load(tmp_path / d / "accuracy/paper-sim/mpf-N30-3s/trial-0.npz")["vx"] for d in ("paper", "default")]
    assert runs[0].shape == runs[1].shape and not np.array_equal(runs[0], runs[1])
    assert main(args + ["--out", str(tmp_path / "paper")]) == 1
    assert "another configuration" in capsys.readouterr().err
