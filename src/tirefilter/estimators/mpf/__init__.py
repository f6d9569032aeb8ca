"""Noise-adaptive marginalized particle filter for tire stiffness, vehicle state and IMU
bias: Algorithm 1 of Berntorp & Di Cairano, "Tire-stiffness and vehicle-state estimation based on
noise-adaptive particle filtering" (IEEE TCST 2018), with the corrections listed in
docs/design.md and derived in docs/derivations.md.

Per particle: the state x (full model [vx, vy, r], lateral model [vy, r]), NiW statistics
of the stiffness deviations w (full [dC_x, dCf_y, dCr_y], lateral [dCf_y, dCr_y]), and a
Gaussian bias estimate (b, P) of the IMU channels. One step at sample k:

  1. propagate x with the w sampled at k-1 (eq. (9), Euler or Heun), predict the bias
     (eq. (29)) and, while learning, forget the statistics (eq. (20));
  2. weight with the Student-t likelihood of eq. (36) (consistent scaling, see
     derivations), normalise in log space, resample when ESS < threshold (every
     per-particle quantity is copied);
  3. Kalman update of the bias, eq. (30);
  4. sample w_k from the conditional Student-t of eq. (39)-(41) given the accelerometer
     residuals, and (gate open) update the statistics with that same w_k, eq. (19);
     project the means onto the stiffness bounds (Sec. V);
  5. report eq. (26)-(27): stiffness mean, posterior std of the mean, deviation spread.

The package, one concern per module:

  config.py          MPFConfig, the options (the `[mpf]` table of --config)
  filter.py          StiffnessMPF: the particles, their initialisation, the model calls
                     (`vehicle.single_track`), the numpy reference step (weight, resample, bias
                     update, sample w, statistics update, forget, propagate), the estimate and
                     the learned state carried between drives
  supervision.py     the learning gate, plausibility, gaps, restarts, the informed start
  adaptation.py      adaptive forgetting, state noise from the data, the
                     std calibration (batch-means sandwich), the undriven axle's share of Cx
  compiled.py        the compiled step (the numba backend's path for every usual sample)
  kernels.py         its numba kernels (`kernels_weigh`, `kernels_update`)
"""

from tirefilter.estimators.mpf.adaptation import cx_excitation_weight
from tirefilter.estimators.mpf.config import MPFConfig
from tirefilter.estimators.mpf.filter import StiffnessMPF

__all__ = ["MPFConfig", "StiffnessMPF", "cx_excitation_weight"]
