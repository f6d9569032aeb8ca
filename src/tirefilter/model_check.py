"""The posterior-predictive check of a run (run.json `model_check`): does the model explain the
data, judged without any reference, from the estimator's one-step predictive of each sample?

At every sample the estimator predicts the measured a^Y and yaw rate before it sees them
(mean m_k and variance V_k of its predictive distribution, `one_step_predictive()`). The
standardised residual z_k = (y_k - m_k) / sqrt(V_k) has mean 0 and mean square 1 given the
past, whatever the predictive's shape, when the data come from the model (docs/derivations.md,
"The model check"). The check groups the samples by the predicted |a^Y| (bins of BIN_WIDTH, the
last open above BIN_TOP) and by time (windows, merged pairwise to stay at most MAX_WINDOWS) and
tests each bin with batch means over BATCH_S-long batches of the drive: a bin is flagged when
the residuals' mean square exceeds 1 + VAR_TOL or their mean, signed toward the predicted a^Y,
exceeds BIAS_TOL in size, each at the run's false-alarm rate ALPHA shared out over the tests
(Bonferroni). The flagged bins name the region of |a^Y| where the model stops explaining the data.

Memory is constant whatever the drive's length: a chunk of CHUNK samples, one open batch per
bin, the sums of the closed batches (mergeable), at most MAX_WINDOWS windows.
"""

from __future__ import annotations

import math

import numpy as np

CHANNELS = ("ay", "yaw_rate")  # the predicted measurements, in the order of `one_step_predictive`
BATCH_S = 5.0  # s, the batches of the batch-means variance (a corner and its exit)
BIN_WIDTH = 0.5  # m/s^2, the bins of the predicted |a^Y|
BIN_TOP = 10.0  # m/s^2, the last bin holds every |a^Y| above
WINDOW_BATCHES = 6  # batches per time window at the start (30 s), doubled each time the windows are merged
MAX_WINDOWS = 64
ALPHA = 0.01  # the false-alarm rate of a run: the share of runs on data from the model itself that warn
VAR_TOL = 1.0  # a bin is flagged when the residuals' mean square exceeds 1 + VAR_TOL (twice the predicted)...
BIAS_TOL = 0.5  # ... or their signed mean exceeds half a predicted std, each beyond the batch-means error
MIN_BATCHES = 5  # a bin with fewer batches (or samples) is reported, not tested
MIN_SAMPLES = 50
CHUNK = 4096

# the sums of one statistic's batches (mergeable: sums of sums): J batches, N samples, and for the
# batch sums X (signed z) and Y (z^2) with n samples each: sum X, sum X^2, sum X n, sum Y, sum Y^2, sum Y n, sum n^2
J, N, SX, SXX, SXN, SY, SYY, SYN, SNN = range(9)
NSUM = 9


def _close_batches(n: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The batch sums (..., NSUM) of batches with n samples, signed sum x and square sum y (each (...,))."""
    out = np.zeros(n.shape + (NSUM,))
    has = n > 0
    out[..., J] = has
    out[..., N] = n
    out[..., SX], out[..., SXX], out[..., SXN] = x, x * x, x * n
    out[..., SY], out[..., SYY], out[..., SYN] = y, y * y, y * n
    out[..., SNN] = n * n
    return out


def ratio_mean_se(s: np.ndarray, which: str) -> tuple[float, float]:
    """The mean over the samples of the batch sums `s` (NSUM,) ("x": signed z, "y": z^2) and its
    batch-means standard error, J/(J-1) sum_j (X_j - theta n_j)^2 / (sum n)^2 (the ratio
    estimator's variance); (NaN, NaN) without samples, se NaN with fewer than 2 batches."""
    sx, sxx, sxn = (s[SX], s[SXX], s[SXN]) if which == "x" else (s[SY], s[SYY], s[SYN])
    n, nb = s[N], s[J]
    if n <= 0:
        return math.nan, math.nan
    theta = sx / n
    if nb < 2:
        return theta, math.nan
    ss = max(sxx - 2.0 * theta * sxn + theta * theta * s[SNN], 0.0)
    return theta, math.sqrt(nb / (nb - 1.0) * ss) / n


def effective_batches(s: np.ndarray) -> float:
    """(sum n_j)^2 / sum n_j^2: the number of equal batches that weigh as the batches of `s` do
    (J for equal batches, fewer where a few batches hold most samples)."""
    return s[N] * s[N] / s[SNN] if s[SNN] > 0 else 0.0


def t_quantile(p: float, dof: float) -> float:
    """The p-quantile of Student's t with `dof` degrees of freedom."""
    from scipy.special import stdtrit

    return float(stdtrit(dof, p))


class PredictiveCheck:
    """The streaming statistics of the check: `add` the samples in time order, `result()` at the end.

    `alpha`, `var_tol`, `bias_tol`: the rule (module constants by default; the tests set the
    tolerances to 0 to measure the false-alarm rate against its nominal value)."""

    def __init__(self, *, alpha: float = ALPHA, var_tol: float = VAR_TOL, bias_tol: float = BIAS_TOL,
                 batch_s: float = BATCH_S):
        self.alpha, self.var_tol, self.bias_tol, self.batch_s = alpha, var_tol, bias_tol, batch_s
        self.nbins = int(round(BIN_TOP / BIN_WIDTH)) + 1
        nc = len(CHANNELS)
        self.bins = np.zeros((nc, self.nbins, NSUM))  # the closed batches' sums per channel and bin
        self.cur = np.zeros((3, nc, self.nbins))  # the open batch: n, sum of signed z, sum of z^2
        self.t0 = None  # the first sample's time
        self.kb = None  # the open batch's index
        self.windows: list[list] = []  # [window index, its last batch, sums (nc, NSUM)], in time order
        self.window_batches = WINDOW_BATCHES
        self.samples = 0
        self.ay_max = 0.0  # the largest predicted |a^Y| checked

    def add(self, t: np.ndarray, ay_pred: np.ndarray, z: np.ndarray) -> None:
        """Samples at times t (n,) with the predicted a^Y (n,) and the standardised residuals
        z (n, 2) of a^Y and the yaw rate (NaN: missing, left out); t increases."""
        t, ay_pred, z = np.asarray(t, float), np.asarray(ay_pred, float), np.asarray(z, float)
        keep = np.isfinite(ay_pred) & np.isfinite(t)
        if not keep.all():
            t, ay_pred, z = t[keep], ay_pred[keep], z[keep]
        if not len(t):
            return
        if self.t0 is None:
            self.t0 = float(t[0])
        kb = np.floor((t - self.t0) / self.batch_s).astype(np.int64)
        bins = np.minimum((np.abs(ay_pred) / BIN_WIDTH).astype(np.int64), self.nbins - 1)
        sz = np.sign(ay_pred)[:, None] * z
        self.ay_max = max(self.ay_max, float(np.max(np.abs(ay_pred))))
        cuts = np.flatnonzero(np.diff(kb)) + 1
        for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(t)]):
            if self.kb is not None and kb[lo] != self.kb:
                self._close()
            self.kb = int(kb[lo])
            b = bins[lo:hi]
            for c in range(len(CHANNELS)):
                zc = z[lo:hi, c]
                ok = np.isfinite(zc)
                if not ok.any():
                    continue
                bc = b[ok]
                self.cur[0, c] += np.bincount(bc, minlength=self.nbins)
                self.cur[1, c] += np.bincount(bc, sz[lo:hi, c][ok], minlength=self.nbins)
                self.cur[2, c] += np.bincount(bc, zc[ok] * zc[ok], minlength=self.nbins)
                self.samples += int(ok.sum()) if c == 0 else 0

    def _close(self) -> None:
        """The open batch into the bins' sums and into its time window (window k holds the
        batches kb with kb // window_batches = k: integers, so that no rounding moves a batch)."""
        n, x, y = self.cur
        self.bins += _close_batches(n, x, y)
        per_channel = _close_batches(n.sum(axis=1), x.sum(axis=1), y.sum(axis=1))  # (nc, NSUM)
        k = self.kb // self.window_batches
        if self.windows and self.windows[-1][0] == k:
            self.windows[-1][1] = self.kb
            self.windows[-1][2] += per_channel
        else:
            self.windows.append([k, self.kb, per_channel])
            if len(self.windows) > MAX_WINDOWS:
                self._merge_windows()
        self.cur[...] = 0.0

    def _merge_windows(self) -> None:
        """Adjacent windows merged in pairs: the window's span doubled."""
        self.window_batches *= 2
        merged: list[list] = []
        for k, last, sums in self.windows:
            if merged and merged[-1][0] == k // 2:
                merged[-1][1] = last
                merged[-1][2] = merged[-1][2] + sums
            else:
                merged.append([k // 2, last, sums.copy()])
        self.windows = merged

    def finish(self) -> None:
        if self.kb is not None and self.cur[0].sum() > 0:
            self._close()
        self.kb = None

    # ---- the tests and the result -------------------------------------------------------------
    def _tested(self, s: np.ndarray) -> bool:
        return s[J] >= MIN_BATCHES and s[N] >= MIN_SAMPLES

    def _judge(self, s: np.ndarray, crit_of) -> dict:
        """One channel of one bin: the mean square and the signed mean with their errors, and
        whether either is beyond its tolerance at the critical t of its batches (`crit_of(dof)`)."""
        v, v_se = ratio_mean_se(s, "y")
        b, b_se = ratio_mean_se(s, "x")
        out = {"var_ratio": _r(v), "var_ratio_se": _r(v_se), "bias": _r(b), "bias_se": _r(b_se)}
        if crit_of is not None and self._tested(s):
            crit = crit_of(effective_batches(s) - 1.0)
            out["flagged"] = bool(v - (1.0 + self.var_tol) > crit * v_se or abs(b) - self.bias_tol > crit * b_se)
        return out

    def result(self) -> dict:
        """The check (run.json `model_check`, docs/design.md): per visited bin of the predicted
        |a^Y| and per time window the residuals' mean square (`var_ratio`, 1 for a calibrated
        model) and signed mean (`bias`, 0; negative: the data fall short of the prediction, a
        saturating tyre), the rule, the flagged region and its warning (None: none)."""
        self.finish()
        nc = len(CHANNELS)
        tested = [(c, b) for c in range(nc) for b in range(self.nbins) if self._tested(self.bins[c, b])]
        n_tests = 3 * len(tested)  # each: mean square above, signed mean above, signed mean below
        level = self.alpha / n_tests if n_tests else self.alpha
        crits: dict[float, float] = {}

        def crit_of(dof: float) -> float:
            dof = round(max(dof, 1.0), 1)
            if dof not in crits:
                crits[dof] = t_quantile(1.0 - level, dof)
            return crits[dof]

        bins = []
        flagged_bins = []
        for b in range(self.nbins):
            s = self.bins[:, b]
            if s[:, N].sum() == 0:
                continue
            lo = b * BIN_WIDTH
            entry = {"ay_abs_from": lo, "ay_abs_to": None if b == self.nbins - 1 else lo + BIN_WIDTH,
                     "samples": int(s[0, N]), "batches": int(s[0, J]), "tested": bool(self._tested(s[0]))}
            for c, name in enumerate(CHANNELS):
                entry[name] = self._judge(s[c], crit_of)
            if any(entry[name].get("flagged") for name in CHANNELS):
                flagged_bins.append(b)
            bins.append(entry)
        span = self.window_batches * self.batch_s
        windows = [{"t_from": round(self.t0 + k * span, 3), "t_to": round(self.t0 + (last + 1) * self.batch_s, 3),
                    "samples": int(s[0, N]), **{name: self._judge(s[c], None) for c, name in enumerate(CHANNELS)}}
                   for k, last, s in self.windows]
        region = region_text(flagged_bins, [b for b in range(self.nbins) if self._tested(self.bins[0, b])])
        worst = None
        if flagged_bins:
            worst = max((e for e in bins if round(e["ay_abs_from"] / BIN_WIDTH) in flagged_bins),
                        key=lambda e: max(e[c]["var_ratio"] or 0.0 for c in CHANNELS))
        return {
            "channels": list(CHANNELS),
            "samples": self.samples,
            "ay_abs_max": _r(self.ay_max),
            "rule": {"alpha": self.alpha, "tests": n_tests, "var_ratio_above": 1.0 + self.var_tol,
                     "abs_bias_above": self.bias_tol, "batch_s": self.batch_s, "bin_width": BIN_WIDTH,
                     "min_batches": MIN_BATCHES, "min_samples": MIN_SAMPLES},
            "bins": bins,
            "windows": windows,
            "region": region,
            "warning": None if region is None else warning_text(region, worst),
        }


def _r(x) -> float | None:
    """A float for JSON: None for NaN, rounded to 4 significant digits."""
    if x is None or not math.isfinite(x):
        return None
    return float(f"{x:.4g}")


def region_text(flagged: list[int], visited: list[int]) -> str | None:
    """The flagged bins as ranges of |a^Y|: "|a^Y| above 4.5 m/s^2" where they reach the highest
    bin tested (`visited`; the bins above it have too few samples to judge), "|a^Y| 2-3 m/s^2"
    otherwise; None when none is flagged."""
    if not flagged:
        return None
    top = max(visited)
    runs: list[list[int]] = []
    for b in sorted(flagged):
        if runs and b == runs[-1][1] + 1:
            runs[-1][1] = b
        else:
            runs.append([b, b])
    if runs == [[0, top]]:
        return "every |a^Y| visited"
    parts = [f"above {lo * BIN_WIDTH:g}" if hi == top else f"{lo * BIN_WIDTH:g}-{(hi + 1) * BIN_WIDTH:g}"
             for lo, hi in runs]
    return "|a^Y| " + ", ".join(parts) + " m/s^2"


def warning_text(region: str, worst: dict | None) -> str:
    """The run's warning: where the model stops explaining the data, and by how much."""
    how = ""
    if worst is not None:
        ay, r = worst["ay"], worst["yaw_rate"]
        lo, hi = worst["ay_abs_from"], worst["ay_abs_to"]
        where = f"above {lo:g}" if hi is None else f"{lo:g}-{hi:g}"
        how = (f" (worst at |a^Y| {where} m/s^2: a^Y residuals {ay['var_ratio']:.3g}x the predicted variance,"
               f" bias {ay['bias']:+.2g} std; yaw rate {r['var_ratio']:.3g}x, {r['bias']:+.2g} std)"
               if ay["var_ratio"] is not None and r["var_ratio"] is not None else "")
    return (f"the model stops explaining the data at {region}{how}: figures from there (stiffness, sideslip) "
            "rest on a model that does not fit")


def summary_line(check: dict | None) -> str | None:
    """The CLI summary's line: the warning, or that the model explains the data over the visited range."""
    if not check or not check.get("samples"):
        return None
    if check["warning"]:
        return f"warning: model check: {check['warning']}"
    return (f"model check: the model explains the data over the visited range (|a^Y| up to "
            f"{check['ay_abs_max']:.3g} m/s^2 predicted, {check['samples']} samples)")


class ModelCheck:
    """The run loop's sink of the check (runs.Run): after each step it reads the estimator's
    `one_step_predictive()` ((mean, var) of a^Y and the yaw rate, and the measured values; None:
    none this step), keeps CHUNK samples and hands them on, and puts the result into the summary
    (`summary.model_check`)."""

    def __init__(self, estimator):
        estimator.predictive_wanted = True  # (the estimator keeps its predictive from its next step on)
        self.check = PredictiveCheck()
        self.buf = np.empty((CHUNK, 4))  # t, predicted a^Y, z of a^Y, z of the yaw rate
        self.n = 0
        self._t = None

    def stepped(self, estimator, est) -> None:
        p = estimator.one_step_predictive()
        if p is None:
            return
        t, mean, var, y = p
        row = self.buf[self.n]
        row[0], row[1] = t, mean[0]
        for c in range(2):
            row[2 + c] = (y[c] - mean[c]) / math.sqrt(var[c]) if var[c] > 0 else math.nan
        self.n += 1
        if self.n == CHUNK:
            self.flush()

    def flush(self) -> None:
        if self.n:
            b = self.buf[:self.n]
            self.check.add(b[:, 0], b[:, 1], b[:, 2:])
            self.n = 0

    def summarize(self, summary) -> None:
        self.flush()
        if self.check.samples:
            summary.model_check = self.check.result()


def has_predictive(estimator) -> bool:
    """Whether the estimator gives its one-step predictive of the measurements."""
    return callable(getattr(estimator, "one_step_predictive", None))
