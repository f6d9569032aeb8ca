"""Compiled (numba, nopython, cached) kernels of the stiffness MPF: `StiffnessMPF.step` for
every sample (`CompiledStep._step_compiled`, compiled.py) in three passes over
the particles, each a loop of straight per-particle arithmetic on arrays the caller allocated
once and reuses from sample to sample. This module gathers them; the code is in
`kernels_weigh` (predict_weigh) and `kernels_update` (resample_gate, sample_update), the
vehicle model's per-particle code in its compiled twin `vehicle.single_track_numba`:

  predict_weigh   step 1 and 2: the wheel slip over the step (derivations, "Wheel slip"),
                  propagation (eq. (9), Euler or Heun with w and the wheel slip held,
                  sub-steps), state noise, bias prediction (eq. (29)), forgetting
                  (eq. (20)), the model at x_k (eq. (1)-(4): a + B w, also the first stage of
                  the next propagation), plausibility, h, d of eq. (12), the predictive of the
                  NiW (eq. (21)) and the Student-t likelihood of eq. (36), the adaptive
                  forgetting's innovation, log-sum-exp and the ESS
  resample_gate   systematic resampling (ancestor indices and the copies of the particles'
                  arrays) and the weighted moments of the gate (Sec. V)
  sample_update   step 3-5: the conditional Student-t of eq. (39)-(41) and its draw, the
                  outlier mask, the bias Kalman update (eq. (30)), the drift of the adaptive
                  forgetting, the NiW update (eq. (19)) with the projection of Sec. V, and the
                  moments of eq. (26)-(27)

and, for the options that need them, `match_state_noise` (the state noise from the data) and
`walk_roll` (the roll gradient's random walk and the roll gain per particle).

Why three passes and not one kernel per stage: at N = 500 a stage does a few hundred
nanoseconds of arithmetic per particle, and a dozen numba calls per sample with their
argument checks, fresh output arrays and re-reads of the model's outputs cost as much
(docs/performance.md, "Backends"). The per-particle code is written inline in the
loops: views of per-particle rows (x[i]) passed to helper functions cost a reference count
each and measured slower.

Inside a pass, the stages whose arithmetic is a chain of dependent square roots, divisions
and logarithms (the 3 x 3 Cholesky factorisations, the triangular solves, the Student-t
density, the wheel slip over the step) each run in a short loop of their own over the
particles, reading and writing the per-particle arrays: in one long loop body the CPU
cannot overlap one particle's chain with the next particle's, in a short one it does
(docs/performance.md, "Backends"). The weights (`_weigh`) and the
conditional draw with the learning (`_sample`) are inlined functions that the passes call
with the sizes (n_w, the available channels, the accelerometer channels) as constants in the
usual cases, the full model with every channel and the lateral model, so that the compiler
unrolls their small loops; other sizes (a missing sample) take the same code with the sizes
as variables. Each case is a signature of its own of the one entry point (`predict_weigh`, the
same for `sample_update`), picked by the number of dimensions of the empty array `sizes` that
the caller passes last (`SIZES_FULL`, `SIZES_LATERAL`, `SIZES_ANY`: the sizes are then constants
of the argument's type), so that a run compiles only the ones it calls, each once (one entry point per case calling the
pass's body with the sizes as literals compiled each case twice, its body and the entry point
that linked it in; inlining the body into the entry point instead took a third more compile:
docs/development.md, "How long `make test` takes").

In `predict_weigh` the propagation evaluates the model on scalars (`_model_t`, `_xdot_t` of the
model's compiled twin, `vehicle.single_track_numba`: the model's a, B and dx/dt returned, not
stored in scratch arrays and read back, so that LLVM keeps them in registers; 1.6-2x faster on
that stage, bit for bit the same numbers); the twin's other kernels keep `_model1`, which
computes the same expressions into arrays. `predict_weigh`'s loops stay scalar
(one particle at a time): LLVM vectorises a loop across particles only over one array per
component and with numba's internal `noalias` flag, and the transposes into such arrays cost
more than the vector lanes save (docs/performance.md, "Backends"). The bias update of
`sample_update` with every channel runs in blocks of 32 particles instead (`_bias_lanes`): its
inputs gathered into block arrays with the particle innermost, each step a loop over the lanes
that LLVM runs in AVX2 registers, the operations per particle those of the scalar code in the
same order (bit for bit the same numbers).

The numpy methods of `StiffnessMPF` (filter.py) are the readable reference; the kernels compute the
same expressions in the same order, one particle at a time, and consume random numbers
drawn by the caller with the reference's generator calls, so both backends follow the same
path (tests/test_kernels.py: equal to 1e-12 relative, full and lateral models, bias on and
off, resampling, missing samples, sub-steps and restarts; the sums of `match_state_noise` run in
another order than numpy's, so there the two agree to rounding only). The kernels compile on first use
and are cached beside their modules.
"""

from tirefilter.estimators.mpf.kernels_update import (estimate_moments, match_state_noise, resample_gate,
                                                      sample_update, walk_roll)
from tirefilter.estimators.mpf.kernels_weigh import SIZES_ANY, SIZES_FULL, SIZES_LATERAL, predict_weigh

__all__ = ["SIZES_ANY", "SIZES_FULL", "SIZES_LATERAL", "estimate_moments", "match_state_noise", "predict_weigh", "resample_gate", "sample_update", "walk_roll"]
