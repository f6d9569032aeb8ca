"""The `tirefilter` command."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from tirefilter import __version__
from tirefilter.config import read_toml
from tirefilter.errors import ConfigError, TirefilterError

from tirefilter.compiling import CompileWatch
from tirefilter.estimators import ESTIMATORS
from tirefilter.viz.options import DEFAULT_LOG_EVERY
from tirefilter.viz.units import scale, unit

SENSOR_CHECK_S = 10.0  # s: a co-simulation's sensor noise is checked against its first seconds


def cmd_run(args) -> int:
    from tirefilter.cosim.run import run_scenario
    from tirefilter.estimators import build, for_scenario, resolve_model
    from tirefilter.runs import SummaryJson
    from tirefilter.scenarios import load_scenario

    scenario = load_scenario(args.scenario)
    config = read_toml(args.config) if args.config else {}
    compiling = _compile_watch(args)
    with compiling:
        estimator = build(args.estimator, for_scenario(scenario), model=args.model, particles=args.particles,
                          config=config)
    _init_state(args, estimator)
    out = Path(args.out) if args.out else Path("runs") / scenario.name
    out.mkdir(parents=True, exist_ok=True)
    results = out / "results.csv"
    model = getattr(getattr(estimator, "cfg", None), "model", None) or resolve_model(args.model, scenario.sensors)

    def record() -> dict:  # run.json's fields besides the summary's, once the run is over
        _check_sensors(estimator, results)
        return dict(command=sys.argv, model=model, fmi_version=args.fmi, compile_s=compiling.seconds,
                    **_estimator_record(estimator, config, args))

    summary = _run_and_report(
        lambda: run_scenario(scenario, estimator=estimator, seed=args.seed, fmi_version=args.fmi, results_csv=results,
                             recording=_recording(args), progress=_progress(args), coupling=args.coupling,
                             friction_csv=_friction_csv(estimator, out / "friction.csv"),
                             sinks=[SummaryJson(out / "run.json", record)]),
        results, compiling)
    if summary is None:
        return 1
    print(f"scenario {scenario.name}: {summary.steps} samples over {scenario.duration:g} s "
          f"({summary.communication_steps} FMU steps of {scenario.communication_step:g} s, FMI {args.fmi}.0), "
          f"estimator {summary.estimator}, seed {args.seed}")
    _print_timing(summary, scenario.duration, compiling)
    _print_sensors(estimator)
    _print_truth_summary(results)
    _print_metrics(summary, estimator)
    print(f"results: {results}\nsummary: {out / 'run.json'}" + (f"\nrecording: {args.rrd}" if args.rrd else "")
          + _streamed(args))
    _print_friction(estimator, out / "friction.csv")
    _save_state(args, estimator)
    return 0


def cmd_replay(args) -> int:
    from tirefilter.estimators import build, for_log, resolve_model
    from tirefilter.replay import replay_log
    from tirefilter.replay.stream import scan_log
    from tirefilter.runs import SummaryJson
    from tirefilter.vehicle.params import load_vehicle

    results = Path(args.out)
    summary_json = results.with_suffix(".json")
    if summary_json == results:
        raise ConfigError("--out", "", f"{results}: the Result CSV needs another suffix than .json (the run summary "
                          "goes to its stem + .json)")
    vehicle = load_vehicle(args.vehicle)
    log = scan_log(args.log, vehicle, vehicle_name=args.vehicle)  # a first pass; the replay streams the file
    for warning in log.plausibility.warnings():
        print(f"warning: {warning}", file=sys.stderr)
    config = read_toml(args.config) if args.config else {}
    setting = for_log(vehicle, log.t, log.signals, source=log.path)
    log.release()  # the setting keeps nothing of the log's length: neither does the replay from here on
    compiling = _compile_watch(args)
    with compiling:
        estimator = build(args.estimator, setting, model=args.model, particles=args.particles, config=config)
    _init_state(args, estimator)
    model = getattr(getattr(estimator, "cfg", None), "model", None) or resolve_model(args.model, log.available)
    summary = _run_and_report(
        lambda: replay_log(log, estimator=estimator, seed=args.seed, results_csv=results, recording=_recording(args),
                           progress=_progress(args), vehicle_file=args.vehicle,
                           friction_csv=_friction_csv(estimator, _friction_name(results)),
                           sinks=[SummaryJson(summary_json, lambda: dict(command=sys.argv, model=model,
                                                                         compile_s=compiling.seconds,
                                                                         **_estimator_record(estimator, config,
                                                                                             args)))]),
        results, compiling)
    if summary is None:
        return 1
    rate = (log.rows - 1) / log.duration if log.duration > 0 else float("nan")
    print(f"replay of {log.path}: {log.rows} rows over {log.duration:g} s ({rate:.4g} Hz on average), "
          f"estimator {summary.estimator}" + (f" ({model} model, N = {estimator.cfg.particles})"
                                              if hasattr(getattr(estimator, "cfg", None), "particles") else "")
          + f", seed {args.seed}")
    _print_timing(summary, log.duration, compiling)
    _print_sensors(estimator)
    q = estimator.state_noise_estimated() if callable(getattr(estimator, "state_noise_estimated", None)) else None
    if q:
        print("state process noise (std), estimated from the log at its end: "
              + ", ".join(f"{n} {v:.3g} {unit(n)}/sqrt(s)" for n, v in q.items())
              + " (docs/derivations.md, 'State noise from the data')")
    final = summary.final or {}
    estimates = [f"{p} {final[p] * scale(p):.4g} +- {final[p + '_std'] * scale(p):.2g} {unit(p)}"
                 for p in ("Cf_y", "Cr_y", "Cx") if final.get(p) is not None and final.get(p + "_std") is not None]
    if estimates:
        print(f"final stiffness at t = {final['t']:g} s: {', '.join(estimates)} (mean +- posterior std of the mean)")
    _print_metrics(summary, estimator)
    print(f"results: {results}\nsummary: {summary_json}" + (f"\nrecording: {args.rrd}" if args.rrd else "")
          + _streamed(args))
    _print_friction(estimator, _friction_name(results))
    _save_state(args, estimator)
    return 0


def cmd_peer_drive(args) -> int:
    from tirefilter.peer.drive import DriveSpec, describe, simulate, write_drive
    from tirefilter.peer.sensors import SensorSpec

    if args.duration <= 0:
        raise ConfigError("--duration", "", f"must be > 0 s, got {args.duration:g}")
    spec = DriveSpec(model=args.model, vehicle=args.vehicle, maneuver=args.maneuver, duration=args.duration,
                     seed=args.seed, speed=args.speed, ay=args.ay, cornering_per_deg=args.cornering_per_deg,
                     sensors=SensorSpec().scaled(noise=args.noise_scale, bias=args.bias_scale),
                     roll_gradient_in_vehicle=args.with_roll_gradient, camber=args.camber, dropouts=args.dropouts,
                     imu_x=args.imu_x, imu_y=args.imu_y, relaxation_in_vehicle=args.with_relaxation)
    drive = simulate(spec)
    log, vehicle = write_drive(drive, args.out, args.vehicle_toml)
    print(describe(drive))
    print(f"log: {log}" + (f"\nvehicle: {vehicle}" if vehicle else ""))
    return 0


def cmd_check_log(args) -> int:
    from tirefilter.replay import check_log

    summary = check_log(args.log, args.vehicle)
    print(json.dumps(summary.to_dict(), indent=2) if args.json else summary.format())
    return 0


def _init_state(args, estimator) -> None:
    if args.init_state:
        from tirefilter.estimators.state_file import load_state

        load_state(estimator, args.init_state)


def _save_state(args, estimator) -> None:
    if args.save_state:
        from tirefilter.estimators.state_file import save_state

        print(f"stiffness posterior: {save_state(estimator, args.save_state)}")


def _recording(args):
    """The Rerun recording of --rrd, --spawn, --connect and --log-every (None: none)."""
    from tirefilter.viz.options import RecordingOptions, recording_options

    return recording_options(recording=RecordingOptions(rrd=args.rrd, spawn=args.spawn, connect=args.connect,
                                                        log_every=args.log_every))


def _streamed(args) -> str:
    return (f"\nstreamed to: {args.connect}" if args.connect else "") + (
        "\nstreamed to: the spawned Rerun viewer" if args.spawn else "")


def _friction_name(results: Path) -> Path:
    from tirefilter.io.friction import friction_csv_path

    return friction_csv_path(results)


def _friction_csv(estimator, path: Path) -> Path | None:
    """Where a friction estimator's curve snapshots go (None for the others)."""
    return path if callable(getattr(estimator, "friction", None)) else None


def _print_friction(estimator, path: Path) -> None:
    """The friction CSV and the slip-clipping count of a friction estimator."""
    if not callable(getattr(estimator, "diagnostics", None)):
        return
    d = estimator.diagnostics()
    print(f"friction curves: {path}")
    print(f"slip angles outside [-L, L] (clipped): {d['slip_clipped_samples']} of {d['particle_slip_evaluations']} "
          f"particle evaluations, at {d['slip_clipped_steps']} steps"
          + (f"; prior handed over from the MPF at t = {d['handover_time']:g} s" if d.get("handover_time") is not None
             else ""))
    if "divergences" in d:
        print(f"divergences detected and recovered: {len(d['divergences'])}"
              + ("".join(f"\n  t = {v['t_onset']:g} s ({v['cause']}): {v['detail']}; {v['action']}"
                         for v in d["divergences"])))


def _progress(args) -> bool | str:
    """The progress of a run on stderr: a bar on a terminal, a line every few seconds
    otherwise ("lines": a log, CI), none with --quiet."""
    if args.quiet:
        return False
    return True if sys.stderr.isatty() else "lines"


def _compile_watch(args) -> CompileWatch:
    """The watch on the numba kernels' one-time compile: announced on stderr (unless
    --quiet) when it starts, its time printed apart from the run's."""
    def announce(text: str) -> None:
        print(("\n" if sys.stderr.isatty() else "") + text, file=sys.stderr, flush=True)

    return CompileWatch(None if args.quiet else announce)


def _estimator_record(estimator, config: dict, args) -> dict:
    """N, the full estimator configuration and the IMU model it assumed (`sensors`) for the
    run summary JSON (with the state file it started from, if any)."""
    est_config = estimator.config_dict() if hasattr(estimator, "config_dict") else dict(config)
    if args.init_state:
        est_config["init_state"] = str(args.init_state)
    sensors = getattr(estimator, "sensors", None)
    return {"particles": getattr(getattr(estimator, "cfg", None), "particles", None), "estimator_config": est_config,
            "sensors": sensors.to_dict() if sensors is not None else None}


def _check_sensors(estimator, results: Path) -> None:
    """A co-simulation's IMU model checked against the noise of the run's first seconds
    (`estimator.sensors` gets the figures and any warning)."""
    from tirefilter.io.results import read_results
    from tirefilter.estimators.sensors import CHANNELS, checked_against, first_seconds

    if getattr(estimator, "sensors", None) is None or not results.exists():
        return
    r = read_results(results, max_rows=int(SENSOR_CHECK_S * 1000) + 1,  # the first seconds (up to 1 kHz), not all
                     columns=["t", *(f"meas_{c}" for c in CHANNELS)])
    if "t" not in r or not len(r["t"]):
        return
    signals = first_seconds(r["t"], {c: r[f"meas_{c}"] for c in CHANNELS if f"meas_{c}" in r}, SENSOR_CHECK_S)
    estimator.sensors = checked_against(estimator.sensors, signals, f"the first {SENSOR_CHECK_S:g} s")


def _run_and_report(run, results: Path, compiling: CompileWatch):
    """`run()` -> (summary, rows), whose sinks write the run summary JSON whether the run
    succeeds, fails (status "failed") or is interrupted, under the watch on the kernels'
    compile (`compiling`: its seconds inside the run go to `summary.compile_s`). Returns the
    summary, None on a failure (said on stderr)."""
    from tirefilter.runs import Interrupted

    try:
        before = compiling.seconds
        with compiling:
            summary, _ = run()
        summary.compile_s = compiling.seconds - before  # of the run's wall time
    except Interrupted as exc:
        summary = getattr(exc, "summary", None)
        at = f" at t = {summary.t_reached:g} s" if summary is not None and summary.t_reached is not None else ""
        print(f"interrupted by {signal_name(exc.signum)}{at}: {summary.steps if summary else 0} whole rows in "
              f"{results}, run summary with status \"interrupted\"", file=sys.stderr)
        raise
    except TirefilterError as exc:
        print(f"error: {exc}\n(rows up to the failure are in {results})", file=sys.stderr)
        return None
    return summary


def _print_timing(summary, duration: float, compiling: CompileWatch) -> None:
    """The one-time compile of the kernels (if this run compiled them) on its own line; the
    wall time of the run without it, its real-time factor and the median step."""
    if compiling.kernels:
        print(f"compile {compiling.seconds:.1f} s: the estimator's numba kernels ({compiling.kernels}), once for "
              "this code on this machine (cached for later runs; not in the wall time below)")
    wall = max(summary.wall_time_s - getattr(summary, "compile_s", 0.0), 1e-9)
    print(f"wall time {wall:.2f} s ({duration / wall:.0f}x real time)"
          + (f", median step {summary.median_step_us:.1f} us" if summary.median_step_us else ""))


def _print_sensors(estimator) -> None:
    if getattr(estimator, "sensors", None) is not None:
        print("\n".join(estimator.sensors.describe()))


def _print_truth_summary(results: Path) -> None:
    import numpy as np

    from tirefilter.io.results import iter_results

    rows = [("speed vx [m/s]", "true_vx"), ("lateral acc. ay [m/s^2]", "true_ay"), ("yaw rate [rad/s]", "true_yaw_rate"),
            ("slip angle front [deg]", "true_alpha_f"), ("wheel slip front [-]", "true_lambda_f"),
            (f"Cf_y surface mean [{unit('Cf_y')}]", "true_Cf_y_mean"),
            (f"Cr_y surface mean [{unit('Cr_y')}]", "true_Cr_y_mean")]
    lo, hi, total, n = {}, {}, {}, 0
    # chunk by chunk: a long run's table is not loaded whole; only the columns printed are parsed
    for r in iter_results(results, columns=["t", *(col for _, col in rows)]):
        n += len(r["t"])
        for _, col in rows:
            x = r[col]
            lo[col] = min(lo.get(col, np.inf), np.min(x))
            hi[col] = max(hi.get(col, -np.inf), np.max(x))
            total[col] = total.get(col, 0.0) + float(np.sum(x))
    print(f"{'truth':28s}{'min':>12s}{'mean':>12s}{'max':>12s}")
    for label, col in rows:
        k = scale(col)  # as the recording shows it: kN/rad, deg (viz/units.py)
        print(f"{label:28s}{k * lo[col]:12.4g}{k * total[col] / n:12.4g}{k * hi[col]:12.4g}")


def _print_metrics(summary, estimator) -> None:
    """The accuracy and health lines of `metrics.format_metrics` (run.json `metrics`), the
    yaw rate's error beside the gyro's white noise the estimator assumes, and the model check's
    line (run.json `model_check`: its warning, or that the model explains the data)."""
    from tirefilter.metrics import format_metrics
    from tirefilter.model_check import summary_line

    sensors = getattr(estimator, "sensors", None)
    noise = {"yaw_rate": (float(sensors.sigma[2]), "gyro")} if sensors is not None else None
    if summary.metrics:
        print("\n".join(format_metrics(summary.metrics, noise)))
    line = summary_line(summary.model_check)
    if line:
        print(line)


def cmd_scenarios(args) -> int:
    from tirefilter.scenarios import list_scenarios

    scenarios = list_scenarios()
    if args.json:
        print(json.dumps([s.summary() for s in scenarios], indent=2))
        return 0
    for s in scenarios:
        windows = ", ".join(f"{a:g}-{b:g} s" for a, b in s.excitation)
        changes = ", ".join(f"{t:g} s" for t in s.surface_changes) or "none"
        print(f"{s.name}\n  {s.description}\n  {s.duration:g} s, estimator {s.estimator_rate:g} Hz, "
              f"{s.model.tire_model} tires, sensors {', '.join(s.sensors)}\n"
              f"  excitation {windows}; surface changes {changes}\n  source: {s.source}")
    return 0


def cmd_fmu_build(args) -> int:
    from tirefilter.cosim.fmu import build_vehicle_fmu

    versions = ("2", "3") if args.fmi == "all" or (args.fmi is None and args.target == "all") else (args.fmi or "2",)
    built = []
    if args.target in ("vehicle", "all"):
        for version, path in build_vehicle_fmu(versions=("2", "3") if args.fmi is None else versions).items():
            print(f"built vehicle FMU (FMI {version}.0): {path}")
            built.append(path)
    if args.target in ("estimator", "all"):
        from tirefilter.fmu_export.build import build_driver_fmu, build_estimator_fmus

        for (name, version), path in build_estimator_fmus(fmi=versions).items():
            print(f"built estimator FMU {name} (FMI {version}.0, {'pythonfmu3' if version == '3' else 'pythonfmu'}): "
                  f"{path}")
            built.append(path)
        if args.target == "all":
            for version in versions:
                path = build_driver_fmu(args.scenario, fmi=version)
                print(f"built driver FMU of {args.scenario} (FMI {version}.0): {path}")
                built.append(path)
    if args.target in ("ssp", "all"):
        from tirefilter.fmu_export.ssp import build_ssp

        from tirefilter.fmu_export.ssp import surface_connected
        from tirefilter.scenarios import load_scenario

        path = build_ssp(args.scenario, seed=args.seed, particles=args.particles)
        print(f"built SSP of {args.scenario} (driver -> vehicle -> estimator, seed {args.seed}): {path}")
        if surface_connected(load_scenario(args.scenario)):
            print("note: the scenario changes the surface, so the SSP connects it; fmpy's simulate_ssp starts "
                  "connectors at 0, which the vehicle rejects (docs/fmu.md, 'The SSP')")
    if built:
        from fmpy.validation import validate_fmu

        problems = {p: validate_fmu(str(p)) for p in built}
        for path, found in problems.items():
            for problem in found:
                print(f"error: {path.name}: {problem}", file=sys.stderr)
        if any(problems.values()):
            return 1
        print(f"validated {len(built)} FMUs with fmpy.validation.validate_fmu: no problems")
    return 0


def _names(values):
    """A list option given space- or comma-separated ("augpf,rls ekf"), None when unset."""
    return tuple(e for v in values for e in v.split(",") if e) if values else None


def cmd_bench_stiffness(args) -> int:
    from tirefilter.study.stiffness import PARTS, StudyOptions, run_stiffness_study

    opts = StudyOptions(out=Path(args.out), parts=tuple(args.part or PARTS), trials=args.trials,
                        particles=tuple(args.particles) if args.particles else None,
                        scenarios=tuple(args.scenario) if args.scenario else None,
                        estimators=_names(args.estimators), workers=args.workers, scheduler=args.scheduler,
                        seed=args.seed, duration=args.duration, plots=not args.no_plots,
                        progress=sys.stderr.isatty() and not args.quiet,
                        config=read_toml(args.config) if args.config else {})
    from tirefilter.runs import Interrupted

    try:
        run_stiffness_study(opts)
    except Interrupted as exc:
        print(f"interrupted by {signal_name(exc.signum)}: the finished trials are kept in {opts.out}; the same "
              "command resumes where it stopped", file=sys.stderr)
        raise
    print(f"report: {opts.out / 'report.md'}")
    return 0


def cmd_dashboard(args) -> int:
    serve = import_viewer().serve
    serve(host=args.host, port=args.port, **({"data_dir": args.data_dir} if args.data_dir else {}))
    return 0


def import_viewer():
    """The dashboard package (`viewer/tirefilter_viewer`): installed with the project, or
    else found next to `src/` in a checkout whose install predates it."""
    try:
        import tirefilter_viewer
    except ImportError:
        from tirefilter.cosim.fmu import REPO_ROOT

        folder = REPO_ROOT / "viewer"
        if not (folder / "tirefilter_viewer" / "__init__.py").is_file():
            raise TirefilterError("the dashboard (viewer/tirefilter_viewer) is not installed: it ships with the "
                                  "repository checkout; install it with `pip install -e .`") from None
        sys.path.insert(0, str(folder))
        import tirefilter_viewer
    return tirefilter_viewer


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="tirefilter", description=__doc__)
    p.add_argument("--version", action="version", version=f"tirefilter {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="co-simulate a scenario against the vehicle FMU")
    run.add_argument("--scenario", required=True, help="scenario name (see `tirefilter scenarios`) or TOML file")
    _estimator_options(run, default="mpf", particles="default from the scenario")
    run.add_argument("--out", help="output folder (default runs/<scenario>)")
    run.add_argument("--fmi", default="2", choices=("2", "3"), help="vehicle FMU version (default 2)")
    run.add_argument("--coupling", default="gauss-seidel", choices=("gauss-seidel", "jacobi"),
                     help="master coupling: gauss-seidel (default: inputs of t_k set before the outputs of t_k are "
                     "read) or jacobi (values exchanged once per step, as fmpy's SSP master; docs/using-the-fmus.md)")
    _output_options(run)
    run.set_defaults(func=cmd_run)

    rp = sub.add_parser("replay", help="run an estimator over a recorded log (Log CSV)")
    rp.add_argument("log", help="the log: Log CSV (or .csv.gz) with t, delta, ax, ay, yaw_rate, vx and/or omega_f, omega_r")
    rp.add_argument("--vehicle", required=True, help="vehicle TOML (parameters, nominal stiffness, sensor noise)")
    _estimator_options(rp, default="mpf", particles="default 500")
    rp.add_argument("--out", required=True, help="Result CSV to write; the run summary goes to its stem + .json")
    _output_options(rp)
    rp.set_defaults(func=cmd_replay)

    ck = sub.add_parser("check-log", help="check a recorded log and summarise what it holds")
    ck.add_argument("log", help="the log: Log CSV (or .csv.gz)")
    ck.add_argument("--vehicle", help="vehicle TOML (steering ratio, wheel radius)")
    ck.add_argument("--json", action="store_true", help="machine-readable summary")
    ck.set_defaults(func=cmd_check_log)

    pd = sub.add_parser("peer-drive", help="generate a test drive (Log CSV + vehicle TOML) from the CommonRoad vehicle "
                        "models (needs the `peer` extra) or the two-track model",
                        description="Simulate a drive with an independent published vehicle model (CommonRoad "
                        "vehiclemodels: single-track drift STD or multi-body MB with body roll, Pacejka tires) or the "
                        "two-track model TT (four wheels, load transfer, load-sensitive Magic Formula tyres with "
                        "relaxation, IMU off the CG, logger dropouts), add a MEMS IMU with biases and noise (on the "
                        "rolling body for MB and TT) and wheel-speed noise, and "
                        "write a Log CSV with *_true reference columns and a vehicle TOML of data-sheet values "
                        "(guessed nominal stiffness, no noise or bias keys).")
    pd.add_argument("--model", default="std", choices=("std", "mb", "tt"),
                    help="peer model (default std; tt: the two-track model written from the textbooks, "
                    "docs/peer_drives.md)")
    pd.add_argument("--vehicle", type=int, default=2, choices=(1, 2, 3),
                    help="peer parameter set: 1 Ford Escort, 2 BMW 320i, 3 VW Vanagon (default 2)")
    pd.add_argument("--maneuver", default="sine", choices=("sine", "sweep", "steps", "slalom", "mixed"),
                    help="steering maneuver after the straight start (default sine; mixed: a longer random drive)")
    pd.add_argument("--duration", type=float, default=40.0, help="seconds (default 40)")
    pd.add_argument("--seed", type=int, default=0, help="seed of the sensors and of the mixed maneuver")
    pd.add_argument("--speed", type=float, default=20.0, help="set speed in m/s (default 20)")
    pd.add_argument("--ay", type=float, default=3.0, help="peak steady-state lateral acceleration, m/s^2 (default 3)")
    pd.add_argument("--noise-scale", type=float, default=1.0, help="scale of the sensors' white noise (default 1)")
    pd.add_argument("--bias-scale", type=float, default=1.0, help="scale of the IMU biases (default 1; 0: none)")
    pd.add_argument("--cornering-per-deg", type=float, default=0.25,
                    help="rule of thumb for the vehicle TOML's nominal stiffness: cornering coefficient per degree "
                    "times the static axle load (default 0.25)")
    pd.add_argument("--camber", default="off", choices=("off", "continuous", "peer"),
                    help="MB tire camber thrust: off (default; the axle stiffness is the tires'), continuous (the "
                    "Magic Formula's camber terms), peer (as published: offsets that switch sign with the camber)")
    pd.add_argument("--with-roll-gradient", action="store_true",
                    help="also write the MB drive's measured roll gradient (tt: the model's) into the vehicle TOML")
    pd.add_argument("--with-relaxation", action="store_true",
                    help="tt only: also write the tyres' relaxation length (relaxation_length) into the vehicle TOML")
    pd.add_argument("--dropouts", default="auto", choices=("auto", "on", "off"),
                    help="logger dropouts: empty cells, missing rows and one 0.5-1 s gap (auto: on for tt only)")
    pd.add_argument("--imu-x", type=float, help="tt only: IMU position ahead of the CG in m (default the car's, 0.4)")
    pd.add_argument("--imu-y", type=float, help="tt only: IMU position left of the CG in m (default the car's)")
    pd.add_argument("--out", required=True, help="Log CSV to write (.csv or .csv.gz)")
    pd.add_argument("--vehicle-toml", help="vehicle TOML to write (data-sheet values)")
    pd.set_defaults(func=cmd_peer_drive)

    sc = sub.add_parser("scenarios", help="list the scenarios with their schedules")
    sc.add_argument("--json", action="store_true", help="machine-readable list")
    sc.set_defaults(func=cmd_scenarios)

    db = sub.add_parser("dashboard", help="the live web dashboard (viser), on 127.0.0.1 unless --host says otherwise")
    db.add_argument("--port", type=int, default=8080, help="port (default 8080; the next free one if taken)")
    db.add_argument("--host", default="127.0.0.1",
                    help="address to bind (default 127.0.0.1: this machine only; 0.0.0.0 exposes it to the network)")
    db.add_argument("--data-dir", metavar="DIR", help="the folder the paths typed in the page must lie in "
                    "('..' and symlinks out of it are refused; default: the working directory)")
    db.set_defaults(func=cmd_dashboard)

    fmu = sub.add_parser("fmu", help="FMU tools")
    fsub = fmu.add_subparsers(dest="fmu_command", required=True)
    build = fsub.add_parser("build", help="build FMUs from source into $TIREFILTER_FMU_DIR if set, else fmu/build/ "
                            "in a checkout, else ~/.cache/tirefilter/fmu (docs/usage.md)")
    build.add_argument("target", nargs="?", default="vehicle", choices=("vehicle", "estimator", "ssp", "all"),
                       help="vehicle: the C vehicle FMU (FMI 2.0, 3.0); estimator: the estimator FMU(s) (pythonfmu); "
                       "ssp: <build folder>/<scenario>.ssp wiring driver -> vehicle -> estimator; all: all of them")
    build.add_argument("--fmi", choices=("2", "3", "all"),
                       help="FMI version of the Python FMUs (estimator, driver): 2 (default; pythonfmu), 3 (pythonfmu3) "
                       "or all; `all` targets build both; the vehicle FMU is built in both unless this is given")
    build.add_argument("--scenario", default="snow-sine", help="scenario of the SSP (default snow-sine)")
    build.add_argument("--seed", type=int, default=0, help="seed of the SSP's run (default 0)")
    build.add_argument("--particles", type=int, help="N of the SSP's estimator (default: the scenario's)")
    build.set_defaults(func=cmd_fmu_build)

    bench = sub.add_parser("bench", help="Monte-Carlo studies")
    bsub = bench.add_subparsers(dest="bench_command", required=True)
    st = bsub.add_parser("stiffness", help="the stiffness paper's comparisons (Sec. VI, VII): tables, plots",
                         description="Parts: accuracy (paper-sim, 100 trials), particles (v^Y RMSE against N), "
                         "comparison (snow-sine, asphalt-normal: every estimator), cost (step time against N). "
                         "Trials already in --out are not run again.")
    st.add_argument("--part", nargs="+", choices=("accuracy", "particles", "comparison", "cost"),
                    help="parts to run (default: all)")
    st.add_argument("--trials", type=int, help="trials per configuration (default: 100, 20, 50 by part)")
    st.add_argument("--particles", type=int, nargs="+", help="N (default: 500; 50 100 200 500 1000 for particles)")
    st.add_argument("--scenario", nargs="+", help="scenarios (default: by part)")
    st.add_argument("--estimators", nargs="+", help="estimators, space- or comma-separated (default: by part)")
    st.add_argument("--workers", type=int, help="worker processes (default: one per CPU)")
    st.add_argument("--scheduler", metavar="ADDRESS",
                    help="run the trials on this Dask scheduler (tcp://host:8786) instead of local processes "
                         "(the dask extra; docs/dask.md)")
    st.add_argument("--seed", type=int, default=0, help="seed of the study's SeedSequence")
    st.add_argument("--duration", type=float, help="shorten every trial to this many seconds")
    st.add_argument("--config", metavar="FILE.toml",
                    help="estimator options for every trial, as `run --config` takes them ([mpf] slip_hold = ...)")
    st.add_argument("--out", default="runs/bench-stiffness", help="output folder (default runs/bench-stiffness)")
    st.add_argument("--no-plots", action="store_true", help="tables only")
    st.add_argument("--quiet", action="store_true", help="no progress bar")
    st.set_defaults(func=cmd_bench_stiffness)
    return p


def _estimator_options(p: argparse.ArgumentParser, *, default: str, particles: str) -> None:
    """The estimator options `run` and `replay` share (docs/usage.md)."""
    p.add_argument("--estimator", default=default, choices=ESTIMATORS, help=f"estimator (default: {default})")
    p.add_argument("--model", default="auto", choices=("full", "lateral", "auto"),
                   help="estimation model: full (wheel speeds), lateral (vx given), or auto (full with wheel speeds)")
    p.add_argument("--particles", type=int, help=f"number of particles (particle filters; {particles})")
    p.add_argument("--seed", type=int, default=0, help="seed of the run's SeedSequence")
    p.add_argument("--config", help="estimator configuration TOML (the [mpf], [kf], [augpf], [rls], [ekf] or "
                   "[gpssm] table; combined: [gpssm] and [mpf])")
    p.add_argument("--init-state", metavar="FILE", help="start from the stiffness posterior saved by --save-state")
    p.add_argument("--save-state", metavar="FILE", help="save the learned stiffness posterior at the end (JSON)")


def _output_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rrd", help="write a Rerun recording to this file (headless)")
    p.add_argument("--spawn", action="store_true", help="start a local Rerun viewer and stream the run to it")
    p.add_argument("--connect", metavar="ADDR", help="stream the run to a running Rerun viewer or gRPC proxy, "
                   "e.g. rerun+http://127.0.0.1:9876/proxy")
    p.add_argument("--log-every", type=int, default=DEFAULT_LOG_EVERY, metavar="K",
                   help="log particle clouds, posterior densities and friction curves every K estimator steps "
                   f"(series every step; default {DEFAULT_LOG_EVERY})")
    p.add_argument("--quiet", action="store_true",
                   help="no progress (a bar on a terminal, else a line every 5 s) and no compile notice on stderr")


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    particles = getattr(args, "particles", None)
    if any(n < 1 for n in (particles if isinstance(particles, list) else [particles or 1])):
        print(f"error: --particles must be at least 1, got {particles}", file=sys.stderr)
        return 2
    from contextlib import nullcontext

    from tirefilter.runs import Interrupted, interruptible

    try:
        with interruptible() if args.command in INTERRUPTIBLE else nullcontext():
            return args.func(args)
    except Interrupted as exc:
        return exc.exit_code  # 130 (SIGINT) or 143 (SIGTERM)
    except TirefilterError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


INTERRUPTIBLE = ("run", "replay", "bench")  # SIGINT / SIGTERM end them at a row (trial) boundary


def signal_name(signum: int) -> str:
    import signal

    return signal.Signals(signum).name


if __name__ == "__main__":
    sys.exit(main())
