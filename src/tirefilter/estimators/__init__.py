"""Estimators following the protocol of `base.py`, and the registry that builds one by
name (`build`) for a `Setting`: a co-simulated scenario (`for_scenario`) or a vehicle and a
recorded log (`for_log`)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

from tirefilter.errors import ConfigError

BASELINES = ("augpf", "rls", "ekf")
FRICTION_ESTIMATORS = ("gpssm", "combined")


def mpf_config_for_scenario(scenario, *, model: str, particles: int | None, overrides: dict):
    """MPF options from a scenario (initialisation, rates, sensor spec) and the user's
    `[mpf]` table; initial stiffness is relative to the scenario's true surface mean."""
    est = scenario.estimator
    ref = scenario.reference_stiffness()
    params = ("Cx", "Cf_y", "Cr_y") if model == "full" else ("Cf_y", "Cr_y")
    reference = tuple(ref[p] for p in params)
    kw = {"init_reference": reference}
    init = est.get("initial_stiffness", {})
    if init.get("distribution") == "uniform":
        lo, hi = init["low"], init["high"]
        kw.update(init_distribution="uniform", init_half_width=(hi - lo) / 2,
                  init_center=tuple((lo + hi) / 2 * r for r in reference))
    elif init:
        kw.update(init_distribution="normal", init_std=init.get("std", 0.3),
                  init_center=tuple(init.get("mean", 1.0) * r for r in reference))
    if "forgetting" in est:
        kw["forgetting"] = est["forgetting"]
    x0 = est.get("initial_state", {})
    vx0 = scenario.truth.get("vx0", 20.0)
    if "std" in x0:
        kw["x0_std"] = tuple(x0["std"])
    s = scenario.sensor_spec
    kw["bias_rw"] = (s.bias_rw_ax, s.bias_rw_ay, s.bias_rw_yaw_rate)
    kw["bias0_std"] = (s.bias0_std_ax, s.bias0_std_ay, s.bias0_std_yaw_rate)
    # the wandering-offset model where the scenario's road has bank (a flat road has none)
    from tirefilter.estimators.sensors import DISTURBANCE_RW

    kw["disturbance_rw"] = DISTURBANCE_RW if scenario.inputs.components.get("bank") else (0.0, 0.0, 0.0)
    kw["sigma_omega"] = s.sigma_omega  # wheel-speed pre-filter where the wheels are noisy (derivations, "Wheel-speed pre-filter")
    return _mpf_config(model, particles=particles or est.get("particles"), sample_period=scenario.sample_period,
                       sigma=(s.sigma_ax, s.sigma_ay, s.sigma_yaw_rate),
                       x0_mean=tuple(x0.get("mean", (vx0, 0.0, 0.0))), overrides=overrides, **kw)


def mpf_config_for_log(vehicle, t, signals: dict, *, model: str, particles: int | None, overrides: dict,
                       sensors=None):
    """MPF options for a recorded log (no scenario, no truth) and the user's `[mpf]` table.

    Stiffness starts around the vehicle TOML's nominal values (MPFConfig defaults:
    `init_center` None = nominal, `init_std` 0.3), the white noise `sigma` and the bias
    model come from `sensors` (default `sensors.sensors_for_log`: the vehicle TOML's
    figures where given, else the noise estimated from the log and the MEMS bias
    defaults; `sigma_omega`, the wheel speeds' white noise, estimated from the log's wheel
    speeds), `sample_period` is the median time step of
    the log, and the initial state mean is taken from the log's first finite samples:
    full model (v^X, 0, r) with v^X from `vx` or else from the undriven axle's wheel speed
    (R_w omega), lateral model (0, r); r is the first yaw-rate sample (0 if none). The log gives
    no v^Y: `x0_given` is False (the stiffness statistics drawn again once the gate first opens).
    `t` (n,) are the sample times, `signals` maps log signal names to (n,) arrays (NaN =
    missing sample).
    """
    from tirefilter.estimators.sensors import sensors_for_log

    sample_period, first = log_start(t, signals)
    return _mpf_config_for_log_start(vehicle, sample_period, first, model=model, particles=particles,
                                     overrides=overrides, sensors=sensors or sensors_for_log(vehicle, signals))


def log_start(t, signals: dict) -> tuple[float | None, dict[str, float]]:
    """What the estimators' options take from a log besides its noise: the median time step
    (None for a single row) and each signal's first finite sample (NaN where it has none)."""
    import numpy as np

    dt = np.diff(np.asarray(t, float))
    first = {}
    for name, x in signals.items():
        finite = np.isfinite(x)
        k = int(np.argmax(finite)) if finite.size else 0
        first[name] = float(x[k]) if finite.size and finite[k] else math.nan
    return (float(np.median(dt)) if dt.size else None), first


def _mpf_config_for_log_start(vehicle, sample_period: float | None, first_sample: dict, *, model: str,
                              particles: int | None, overrides: dict, sensors):
    """`mpf_config_for_log` from the log's `log_start` and its IMU model `sensors`."""
    def first(name: str) -> float:
        return first_sample.get(name, math.nan)

    r0 = first("yaw_rate")
    r0 = r0 if math.isfinite(r0) else 0.0
    if model == "full":
        vx0 = first("vx")
        if not math.isfinite(vx0):
            vx0 = vehicle.wheel_radius * first("omega_f" if vehicle.drive == "rear" else "omega_r")
        x0_mean = (vx0 if math.isfinite(vx0) else 20.0, 0.0, r0)
    else:
        x0_mean = (0.0, r0)
    # the log starts mid-drive with v^Y unknown: no given initial state (`x0_given`: the stiffness statistics
    # are drawn again once the gate first opens; derivations, "State noise from the data")
    return _mpf_config(model, particles=particles, sample_period=sample_period,
                       sigma=sensors.sigma, bias0_std=sensors.bias0_std, bias_rw=sensors.bias_rw, x0_mean=x0_mean,
                       sigma_omega=sensors.sigma_omega, x0_given=False, overrides=overrides)


def _mpf_config(model: str, *, particles: int | None, sample_period: float | None, sigma, x0_mean, overrides: dict,
                **kw):
    """What a scenario and a log both set, then the user's overrides."""
    from tirefilter.estimators.mpf import MPFConfig

    from tirefilter.estimators.mpf.config import USER_OPTIONS

    defaults = MPFConfig()
    config = MPFConfig(model=model, particles=particles or defaults.particles,
                       sample_period=sample_period or defaults.sample_period, sigma=tuple(sigma),
                       x0_mean=tuple(x0_mean), **kw)
    return apply_overrides(config, overrides, options=USER_OPTIONS)


def apply_overrides(config, overrides: dict, source: str = "--config [mpf]", options=None):
    """`config` with the values of the table `overrides` (a `--config` table, named `source` in
    errors), checked by kind and then by the configuration's `validated()`. `options`: the keys the
    table may set (the MPF's documented `USER_OPTIONS`); default every field of the configuration."""
    if not isinstance(overrides, dict):
        raise ConfigError(source, "", f"expected a table of options, got {overrides!r}")
    known = {f.name: f for f in dataclasses.fields(config)}
    allowed = sorted(known if options is None else options)
    values = {}
    for key, value in overrides.items():
        if key not in allowed:
            raise ConfigError(source, key, f"unknown option (known: {', '.join(allowed)})")
        values[key] = tuple(value) if isinstance(value, list) else value
        _check_type(source, key, values[key], getattr(config, key), str(known[key].type))
    try:
        return dataclasses.replace(config, **values).validated()
    except (TypeError, ValueError, OverflowError, ZeroDivisionError) as exc:  # a check the validator lacks
        raise ConfigError(source, "", f"invalid option values {values!r} ({type(exc).__name__}: {exc})") from None


def _check_type(source, key: str, value, default, annotation: str) -> None:
    """An option's value has its default's kind: a number (not a bool) for a number, a
    bool for a bool, a string for a string, numbers of the same count for a tuple of them
    (None where the annotation allows it). NaN and infinity are numbers; the
    configuration's own `validated()` judges the ranges."""
    def number(x) -> bool:
        return isinstance(x, (int, float)) and not isinstance(x, bool)

    if value is None and "None" in annotation:
        return
    if default is None and annotation.startswith("tuple"):
        ok = isinstance(value, tuple) and all(number(x) for x in value)
    elif default is None:
        ok = number(value) if ("float" in annotation or "int" in annotation) and "str" not in annotation else True
    elif isinstance(default, bool):
        ok = isinstance(value, bool)
    elif number(default):
        ok = number(value) and (not isinstance(default, int) or float(value).is_integer()
                                or "float" in annotation)
    elif isinstance(default, str):
        ok = isinstance(value, str)
    elif isinstance(default, tuple):
        ok = isinstance(value, tuple) and all(number(x) for x in value) and (
            len(value) == len(default) or not default or "..." in annotation)
    else:
        ok = True
    if not ok:
        kind = ("true or false" if isinstance(default, bool) else "a string" if isinstance(default, str) else
                f"{len(default)} numbers" if isinstance(default, tuple) and default else
                "numbers" if isinstance(default, tuple) else "an integer" if isinstance(default, int) and
                "float" not in annotation else "a number")
        raise ConfigError(source, key, f"expected {kind}, got {value!r}")


def resolve_model(model: str, sensors) -> str:
    """`auto` is the full model when wheel speeds are present, else the lateral one."""
    if model != "auto":
        return model
    return "full" if {"omega_f", "omega_r"} <= set(sensors) else "lateral"


def check_model_signals(model: str, signals, source, key: str) -> None:
    """The signals a model needs: the lateral model takes v^X as an input (`vx`), the full
    model the wheel speeds of both axles (`omega_f`, `omega_r`)."""
    missing = {"lateral": ("vx",), "full": ("omega_f", "omega_r")}[model]
    missing = [s for s in missing if s not in set(signals)]
    if missing:
        raise ConfigError(source, key, f"the {model} model needs {' and '.join(missing)} "
                          f"(available: {', '.join(signals) or 'none'})")


def check_tables(config: dict) -> None:
    """The estimator tables of a `--config` file ([mpf], [kf], ..., [guard]) are tables."""
    if not isinstance(config, dict):
        raise ConfigError("--config", "", f"expected tables of options, got {config!r}")
    for name in (*ESTIMATORS, "guard"):
        if name in config and not isinstance(config[name], dict):
            raise ConfigError("--config", name, f"expected a table [{name}] of options, got {config[name]!r}")


def with_guard(estimator, config: dict):
    """`estimator` carrying the measurement guard of `config`'s `[guard]` table as
    `estimator.guard` (estimators.guard; the run loop applies it before every step)."""
    if estimator is not None:
        from tirefilter.estimators.guard import guard_from_config

        estimator.guard = guard_from_config(config)
    return estimator


@dataclass(frozen=True)
class Setting:
    """What an estimator is built for: a co-simulated scenario (`for_scenario`) or a recorded
    log (`for_log`). The defaults in which the two differ are these fields, set in those two
    functions and nowhere else; `build` makes any estimator of REGISTRY from one."""

    vehicle: object  # vehicle.params.VehicleParams
    signals: tuple[str, ...]  # the sensors (scenario) or the log's signals with samples: `auto`, a model's needs
    sensors: object  # sensors.SensorModel: the IMU model the estimator assumes (its `.sensors`)
    source: object  # what an error names: the scenario's file, the log's path
    key: str  # ... and where in it: "sensors" or "columns"
    mpf_config: Callable  # (model, particles, overrides) -> MPFConfig of the MPF and the baselines
    particles: int | None  # the GP-SSM's N when none is asked for (None: GPSSMConfig's)
    sample_period: float | None  # s, the GP-SSM's (None: GPSSMConfig's)
    gpssm: dict  # the GP-SSM's other defaults: sigma (a^Y, yaw rate), x0_mean, tire_shape[, prior_peak]
    kf: dict  # the kf's: sigma_ay, sigma_yaw_rate


def for_scenario(scenario) -> Setting:
    """A co-simulation: the scenario's sensors, its initialisation and rates
    (`mpf_config_for_scenario`), its sensor noise, its true initial state and tire shape."""
    from tirefilter.estimators.sensors import sensors_for_scenario

    s = scenario.sensor_spec
    p = scenario.model.pacejka
    gpssm = {"sigma": (s.sigma_ay, s.sigma_yaw_rate),
             "x0_mean": (scenario.truth.get("vy0", 0.0), scenario.truth.get("yaw_rate0", 0.0)),
             "tire_shape": None if p is None else (p.B_y, p.C_y, p.E_y),
             "bias0_std": (s.bias0_std_ay, s.bias0_std_yaw_rate), "bias_rw": (s.bias_rw_ay, s.bias_rw_yaw_rate),
             "sigma_omega": float(s.sigma_omega), "sigma_ax": s.sigma_ax}
    if "prior_peak_friction" in scenario.estimator:
        gpssm["prior_peak"] = scenario.estimator["prior_peak_friction"]
    return Setting(
        vehicle=scenario.vehicle, signals=tuple(scenario.sensors), sensors=sensors_for_scenario(s),
        source=scenario.file, key="sensors",
        mpf_config=lambda model, particles, overrides: mpf_config_for_scenario(scenario, model=model,
                                                                               particles=particles,
                                                                               overrides=overrides),
        particles=scenario.estimator.get("particles"), sample_period=scenario.sample_period, gpssm=gpssm,
        kf={"sigma_ay": s.sigma_ay, "sigma_yaw_rate": s.sigma_yaw_rate})


def for_log(vehicle, t, signals: dict, source="log") -> Setting:
    """A recorded log: `signals` maps the log's signal names that have samples to (n,) arrays at
    the times `t` (n,); the IMU model comes from the vehicle TOML or is estimated from them
    (`sensors.sensors_for_log`), the MPF's options from them (`mpf_config_for_log`), the
    GP-SSM's sample period is the median time step, its state starts at zero, its tires have no
    known shape and its prior's slope is the vehicle file's stiffness; `source` names the log
    in errors. What is kept of the log is its IMU model and `log_start`, nothing of its
    length: a replay may drop its samples once this is made."""
    from tirefilter.estimators.sensors import sensors_for_log

    sensors = sensors_for_log(vehicle, signals)
    sample_period, first = log_start(t, signals)
    return Setting(
        vehicle=vehicle, signals=tuple(signals), sensors=sensors, source=source, key="columns",
        mpf_config=lambda model, particles, overrides: _mpf_config_for_log_start(
            vehicle, sample_period, first, model=model, particles=particles, overrides=overrides, sensors=sensors),
        particles=None, sample_period=sample_period,
        gpssm={"sigma": sensors.sigma[1:], "x0_mean": (0.0, 0.0), "tire_shape": None,
               "bias0_std": sensors.bias0_std[1:], "bias_rw": sensors.bias_rw[1:], "sigma_omega": sensors.sigma_omega,
               "sigma_ax": sensors.sigma[0], "prior_slope": "vehicle"},
        kf={"sigma_ay": sensors.sigma[1], "sigma_yaw_rate": sensors.sigma[2]})


def build(name: str, setting: Setting, *, model: str, particles: int | None, config: dict):
    """The estimator `name` (None for "none") for `setting`, from the options of `config`
    (a `--config` TOML's tables: `[mpf]`, `[kf]`, ..., `[guard]`), with the IMU model it
    assumes as `.sensors` (a `sensors.SensorModel`) and its measurement guard (`with_guard`).
    The one place where an estimator is made by name: `tirefilter run` and `replay`, the
    studies, the dashboard and the estimator FMUs all come here."""
    check_tables(config)
    estimator = REGISTRY[_known(name)](setting, model=model, particles=particles, config=config)
    return with_guard(_with_sensors(estimator, setting.sensors), config)


def build_estimator(name: str, scenario, *, model: str, particles: int | None, config: dict):
    """`build(name, for_scenario(scenario), ...)`: the estimator of a co-simulation."""
    return build(name, for_scenario(scenario), model=model, particles=particles, config=config)


def build_log_estimator(name: str, vehicle, t, signals: dict, *, model: str, particles: int | None, config: dict,
                        source="log"):
    """`build(name, for_log(vehicle, t, signals, source), ...)`: the estimator of a replay."""
    return build(name, for_log(vehicle, t, signals, source), model=model, particles=particles, config=config)


def _with_sensors(estimator, sensors):
    """`estimator` with `.sensors`: `sensors` after the estimator's own configuration
    (which may override the figures, or have no bias model at all)."""
    if estimator is None:
        return None
    cfg = getattr(estimator, "cfg", None)
    sigma = getattr(cfg, "sigma", None)
    if sigma is not None:
        channels = ("ax", "ay", "yaw_rate") if len(sigma) == 3 else ("ay", "yaw_rate")
    elif getattr(cfg, "sigma_ay", None) is not None:  # the kf (and rls's kf)
        sigma, channels = (cfg.sigma_ay, cfg.sigma_yaw_rate), ("ay", "yaw_rate")
    else:
        channels = ()
    bias0_std, bias_rw = getattr(cfg, "bias0_std", None), getattr(cfg, "bias_rw", None)
    if bias0_std is not None and len(bias0_std) == 2:  # the GP-SSM's (a^Y, yaw rate): no a^X bias
        bias0_std, bias_rw = (0.0, *bias0_std), (0.0, *bias_rw)
    model = sensors.with_config(sigma, bias0_std, bias_rw, channels)
    if not hasattr(cfg, "bias_rw"):
        model = dataclasses.replace(model, bias0_std=(0.0,) * 3, bias_rw=(0.0,) * 3,
                                    bias_source=f"the {estimator.name} estimator has no bias model")
    if hasattr(cfg, "disturbance_rw"):
        model = dataclasses.replace(model, disturbance_rw=tuple(cfg.disturbance_rw))
    estimator.sensors = model
    return estimator


# ---- the registry: name -> (setting, model, particles, config) -> estimator ------------------------

def _none(setting: Setting, *, model: str, particles: int | None, config: dict):
    return None


def _mpf(setting: Setting, *, model: str, particles: int | None, config: dict):
    from tirefilter.estimators.mpf import StiffnessMPF

    model = resolve_model(model, setting.signals)
    check_model_signals(model, setting.signals, setting.source, setting.key)
    return StiffnessMPF(setting.vehicle, setting.mpf_config(model, particles, config.get("mpf", {})))


def _kf_estimator(setting: Setting, *, model: str, particles: int | None, config: dict):
    check_model_signals(_kf_model(model), setting.signals, setting.source, setting.key)
    return _kf(setting.vehicle, config, **setting.kf)


def _baseline_estimator(name: str):
    """A baseline of the stiffness paper (augpf, rls, ekf): the MPF's options for its model
    (the user's `[mpf]` table left out), its own `[<name>]` table on top (`_baseline`)."""
    def make(setting: Setting, *, model: str, particles: int | None, config: dict):
        model = _baseline_model(name, model, setting.signals)
        check_model_signals(model, setting.signals, setting.source, setting.key)
        return _baseline(name, setting.vehicle, setting.mpf_config(model, particles, {}), config)

    return make


def _friction_estimator(combined: bool):
    """The friction GP-SSM; `combined`: with its prior slope from a lateral MPF (the user's
    `[mpf]` table, the MPF's default N)."""
    def make(setting: Setting, *, model: str, particles: int | None, config: dict):
        _check_friction_signals(_friction_model(model), setting)
        mpf = None
        if combined:
            from tirefilter.estimators.mpf import StiffnessMPF

            mpf = StiffnessMPF(setting.vehicle, setting.mpf_config("lateral", None, config.get("mpf", {})))
        return _gpssm(setting.vehicle, config, particles or setting.particles, sample_period=setting.sample_period,
                      mpf=mpf, **setting.gpssm)

    return make


REGISTRY = {
    "none": _none,
    "mpf": _mpf,  # the stiffness MPF (stiffness paper)
    "kf": _kf_estimator,  # linear single-track Kalman filter, fixed stiffness (baseline)
    **{name: _baseline_estimator(name) for name in BASELINES},  # the stiffness paper's baselines (Sec. VI-A, VII)
    "gpssm": _friction_estimator(combined=False),  # friction GP-SSM (friction paper)
    "combined": _friction_estimator(combined=True),  # gpssm with its prior slope from the MPF
}
ESTIMATORS = tuple(REGISTRY)  # --estimator's choices


def _baseline_model(name: str, model: str, sensors) -> str:
    """rls has the lateral model only (v^X given, as in the paper's RLS); augpf and ekf
    resolve `auto` as the MPF does."""
    if name == "rls":
        if model == "full":
            raise ConfigError("--model", "full", "the rls baseline has the lateral model only (v^X given)")
        return "lateral"
    return resolve_model(model, sensors)


def _baseline(name: str, vehicle, mpf_cfg, config: dict):
    """A baseline estimator with the MPF's shared options (prior, sensors, gate, bounds;
    `baseline_common.shared_options`) and the user's `[<name>]` table on top."""
    from tirefilter.estimators.baseline_common import shared_options

    if name == "augpf":
        from tirefilter.estimators.augpf import AugmentedPF as cls, AUGPFConfig as config_cls
    elif name == "rls":
        from tirefilter.estimators.rls import RLSConfig as config_cls, RLSEstimator as cls
    else:
        from tirefilter.estimators.ekf import EKFConfig as config_cls, StiffnessEKF as cls
    return cls(vehicle, shared_options(config_cls, mpf_cfg, config.get(name, {}), f"--config [{name}]"))


def _check_friction_signals(model: str, setting: Setting) -> None:
    """The friction GP-SSM takes v^X from `vx`, else from the undriven axle's wheel speed
    (`gpssm.speed`)."""
    from tirefilter.estimators.gpssm.speed import undriven_wheel

    if "vx" not in setting.signals and undriven_wheel(setting.vehicle) in setting.signals:
        return
    check_model_signals(model, setting.signals, setting.source, setting.key)


def _friction_model(model: str) -> str:
    if model == "full":
        raise ConfigError("--model", "full", "the friction GP-SSM has the lateral model only (v^X given, "
                          "state [v^Y, r], friction paper Sec. 2.1)")
    return "lateral"


def _gpssm(vehicle, config: dict, particles, *, sample_period, sigma, x0_mean, tire_shape, mpf, **kw):
    """The friction GP-SSM (combined with `mpf`): what the scenario or log sets, then the
    user's `[gpssm]` table; settings that cannot work are rejected here, before the run."""
    from tirefilter.estimators.gpssm.filter import FrictionGPSSM, GPSSMConfig

    base = GPSSMConfig(particles=particles or GPSSMConfig.particles,
                       sample_period=sample_period or GPSSMConfig.sample_period, sigma=tuple(sigma),
                       x0_mean=tuple(x0_mean), **kw)
    cfg = apply_overrides(base, config.get("gpssm", {}), "--config [gpssm]")
    return FrictionGPSSM(vehicle, cfg, tire_shape=tire_shape, mpf=mpf)


def _kf_model(model: str) -> str:
    if model == "full":
        raise ConfigError("--model", "full", "the kf baseline has the lateral model only (v^X given)")
    return "lateral"


def _kf(vehicle, config: dict, **defaults):
    """The kf baseline: the vehicle's fixed stiffness, the user's `[kf]` table on top."""
    from tirefilter.estimators.linear_kf import KFConfig, LinearKF

    base = KFConfig(**{k: v for k, v in defaults.items() if k not in config.get("kf", {})})
    return LinearKF(vehicle, apply_overrides(base, config.get("kf", {}), "--config [kf]"))


def _known(name: str) -> str:
    if name not in ESTIMATORS:
        raise ConfigError("--estimator", "", f"unknown estimator {name!r} (available: {', '.join(ESTIMATORS)})")
    return name
