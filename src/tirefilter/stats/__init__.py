"""Statistics for the estimators, batch-first over particles (and trials):
Normal-inverse-Wishart statistics with forgetting, multivariate Student-t, particle
log-weights and resampling.

The names below are imported from their modules when first asked for (PEP 562), so that
importing one module of the package (`stats.noise` for the sensor check of every run) does
not import scipy.special with the Student-t (some 0.3 s of a `tirefilter run --estimator
none`)."""

from importlib import import_module

_MODULE_OF = {
    "NiW": "niw",
    "effective_sample_size": "particles",
    "normalize_log_weights": "particles",
    "systematic_resample": "particles",
    "t_conditional": "student_t",
    "t_logpdf": "student_t",
    "t_sample": "student_t",
}

__all__ = list(_MODULE_OF)


def __getattr__(name: str):
    if name not in _MODULE_OF:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(f"{__name__}.{_MODULE_OF[name]}"), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
