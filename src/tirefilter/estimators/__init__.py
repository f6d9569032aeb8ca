"""Estimators following the protocol of `base.py`, and how a run builds one."""

from __future__ import annotations

import dataclasses

from tirefilter.errors import ConfigError

ESTIMATORS = ("none", "mpf")


def mpf_config_for_scenario(scenario, *, model: str, particles: int | None, overrides: dict):
    """MPF options from a scenario (initialisation, rates, sensor spec) and the user's
    `[mpf]` table; initial stiffness is relative to the scenario's true surface mean."""
    from tirefilter.estimators.stiffness_mpf import MPFConfig

    est = scenario.estimator
    ref = scenario.reference_stiffness()
    full = model == "full"
    params = ("Cx", "Cf_y", "Cr_y") if full else ("Cf_y", "Cr_y")
    reference = tuple(ref[p] for p in params)
    kw = {"model": model, "init_reference": reference, "sample_period": scenario.sample_period}
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
    kw["particles"] = particles or est.get("particles", 500)
    x0 = est.get("initial_state", {})
    vx0 = scenario.truth.get("vx0", 20.0)
    kw["x0_mean"] = tuple(x0.get("mean", (vx0, 0.0, 0.0)))
    if "std" in x0:
        kw["x0_std"] = tuple(x0["std"])
    s = scenario.sensor_spec
    kw["sigma"] = (s.sigma_ax, s.sigma_ay, s.sigma_yaw_rate)
    kw["bias_rw"] = (s.bias_rw_ax, s.bias_rw_ay, s.bias_rw_yaw_rate)
    kw["bias0_std"] = (s.bias0_std_ax, s.bias0_std_ay, s.bias0_std_yaw_rate)
    return apply_overrides(MPFConfig(**kw), overrides)


def apply_overrides(config, overrides: dict, source: str = "--config [mpf]"):
    known = {f.name: f for f in dataclasses.fields(config)}
    values = {}
    for key, value in overrides.items():
        if key not in known:
            raise ConfigError(source, key, f"unknown option (known: {', '.join(sorted(known))})")
        values[key] = tuple(value) if isinstance(value, list) else value
    return dataclasses.replace(config, **values).validated()


def resolve_model(model: str, sensors) -> str:
    """`auto` is the full model when wheel speeds are present, else the lateral one."""
    if model != "auto":
        return model
    return "full" if {"omega_f", "omega_r"} <= set(sensors) else "lateral"


def build_estimator(name: str, scenario, *, model: str, particles: int | None, config: dict):
    if name == "none":
        return None
    if name == "mpf":
        from tirefilter.estimators.stiffness_mpf import StiffnessMPF

        model = resolve_model(model, scenario.sensors)
        if model == "lateral" and "vx" not in scenario.sensors:
            raise ConfigError(scenario.file, "sensors", "the lateral model needs vx")
        cfg = mpf_config_for_scenario(scenario, model=model, particles=particles, overrides=config.get("mpf", {}))
        return StiffnessMPF(scenario.vehicle, cfg)
    raise ConfigError("--estimator", "", f"unknown estimator {name!r} (available: {', '.join(ESTIMATORS)})")
