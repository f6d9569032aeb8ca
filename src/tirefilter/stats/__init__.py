"""Statistics for the estimators, batch-first over particles (and trials):
Normal-inverse-Wishart statistics with forgetting, multivariate Student-t, particle
log-weights and resampling."""

from tirefilter.stats.niw import NiW
from tirefilter.stats.particles import effective_sample_size, normalize_log_weights, systematic_resample
from tirefilter.stats.student_t import t_conditional, t_logpdf, t_sample

__all__ = [
    "NiW",
    "effective_sample_size",
    "normalize_log_weights",
    "systematic_resample",
    "t_conditional",
    "t_logpdf",
    "t_sample",
]
