"""The friction GP-SSM (Berntorp, "Online Bayesian tire-friction learning by Gaussian-process
state-space models", IFAC 2020), one concern per module:

  config.py             GPSSMConfig (the `[gpssm]` table of --config) and the Pacejka prior
  filter.py             FrictionGPSSM: the particles, the numpy reference step, the estimate,
                        the friction curve and the posterior
  compiled.py           the compiled step (the numba backend's path), `CompiledStep`
  kernels_particles.py  its per-particle kernels: propagation, slip, basis and prior (`front`),
                        the weights (`weigh`), the conditional draw (`sample`)
  kernels_stats.py      its kernels over the statistics: the pending update, the forgetting
                        and the predictive in one pass, the rank-one update
  kernels_resample.py   its resampling and the in-place copies
  bias.py               the per-particle IMU bias filters (a^Y, yaw rate)
  speed.py              v^X from the undriven axle's wheel speed (a log without vx)
  supervision.py        divergence: its symptoms, the checkpoints of the statistics
"""

from tirefilter.estimators.gpssm.config import GPSSMConfig
from tirefilter.estimators.gpssm.filter import FrictionGPSSM

__all__ = ["FrictionGPSSM", "GPSSMConfig"]
