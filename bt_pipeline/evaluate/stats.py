"""The statistics of a fair cleaned-vs-noisy verdict for one evaluation cell.

A cell is (task, dataset size, noise kind, learner). Per seed s a learner is trained on the noisy
demos, the cleaned demos and the ground truth of the same set; each trained model gets one score
(a metric's mean over its rollouts). **The samples are the seeds**: the rollouts of one model are
never independent samples, so every function takes per-seed values, shape (S,), index s the same
seed in every array. ``higher_is_better`` orients each difference so that **positive = better**
(success rate and R̄ are higher-is-better, shape distance [mm] lower-is-better).

:func:`verdict` = :func:`truth_gate` (truth must clearly beat noisy, or nothing can be said) +
:func:`paired` (cleaned vs noisy) + :func:`gap_share` (share of the truth-noisy gap recovered);
:func:`holm` adjusts p-values over many cells; :func:`wilson` and :func:`success_curve` describe
one model's rollouts. scipy does the tests (``ttest_rel``, ``wilcoxon``, ``t``,
``binomtest(...).proportion_ci(method="wilson")``). Written here: the bootstrap of
:func:`gap_share` (``scipy.stats.bootstrap`` cannot leave out resamples whose ratio is undefined)
and :func:`holm` (scipy's ``false_discovery_control`` has only Benjamini-Hochberg/-Yekutieli).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.stats
from numpy.typing import ArrayLike

from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError

Outcome = Literal["cannot tell", "cleaned better", "cleaned worse", "no significant difference"]
"""What :func:`verdict` concludes for one cell."""
WILCOXON_MIN_N = 6
"""Fewest non-zero differences for a Wilcoxon p-value (see :func:`paired`)."""


@dataclass(frozen=True)
class PairedTest:
    """b against a over the same seeds; every difference is oriented so positive = b better."""

    n: int
    """Number of seeds (pairs)."""
    mean_diff: float
    """Mean over seeds of (b − a) if higher is better, else (a − b), in the metric's unit."""
    ci: tuple[float, float]
    """Student-t confidence interval of ``mean_diff`` at level ``confidence`` (e.g. 0.95)."""
    confidence: float
    p_t: float
    """Two-sided paired t-test p-value (``scipy.stats.ttest_rel``); NaN if all differences are 0."""
    p_wilcoxon: float
    """Two-sided Wilcoxon signed-rank p-value; NaN with fewer than 6 non-zero differences."""
    wins: int
    """Seeds where b is better."""
    losses: int
    """Seeds where b is worse (the other n − wins − losses are ties)."""


@dataclass(frozen=True)
class Gate:
    """Whether truth (b) clearly beats noisy (a) in ``test``: the precondition of any claim."""

    passed: bool
    test: PairedTest
    alpha: float
    reason: str
    """One line saying why it passed or failed."""


@dataclass(frozen=True)
class GapShare:
    """(mean(cleaned) − mean(noisy)) / (mean(truth) − mean(noisy)): 0 = no gain, 1 = as truth."""

    share: float
    """NaN when truth does not beat noisy on average (no gap to recover)."""
    ci: tuple[float, float]
    """Paired bootstrap percentile interval over seeds at ``confidence``; NaN when undefined."""
    confidence: float
    gap: float
    """Oriented mean(truth) − mean(noisy), in the metric's unit (positive = truth better)."""
    undefined: float
    """Share of bootstrap resamples with no gap (gap ≤ 0), left out of ``ci``."""
    note: str
    """Empty, or why ``share`` or ``ci`` is NaN, or what was left out."""


@dataclass(frozen=True)
class Verdict:
    """The cleaned-vs-noisy conclusion of one cell."""

    outcome: Outcome
    gate: Gate
    cleaned_vs_noisy: PairedTest
    """Computed in every case; a claim is made from it only when the gate passed."""
    gap: GapShare
    alpha: float
    """Level of the two-sided cleaned-vs-noisy test."""

    def summary(self) -> str:
        """One line to read at a glance, e.g. ``cleaned better: gain over noisy +0.03 (...)``."""
        if self.outcome == "cannot tell":
            return f"cannot tell: {self.gate.reason}"
        t, g = self.cleaned_vs_noisy, self.gap
        line = (
            f"{self.outcome}: gain over noisy {t.mean_diff:+.3g} "
            f"({t.confidence:.0%} CI {t.ci[0]:+.3g} to {t.ci[1]:+.3g}; + = cleaned better), "
            f"better in {t.wins}/{t.n} seeds, {_p_text(t.p_t)}"
        )
        if np.isfinite(g.share):
            line += f"; recovers {g.share:.0%} of the truth-noisy gap"
            if np.all(np.isfinite(g.ci)):
                line += f" ({g.confidence:.0%} CI {g.ci[0]:.0%} to {g.ci[1]:.0%})"
        return line


def paired(
    a: ArrayLike, b: ArrayLike, *, higher_is_better: bool, confidence: float = 0.95
) -> PairedTest:
    """Paired comparison of b with a over seeds.

    Args:
        a: Per-seed scores of the reference (e.g. noisy), shape (S,), S ≥ 2.
        b: Per-seed scores of the candidate (e.g. cleaned), shape (S,), same seeds in order.
        higher_is_better: Orientation of the metric; differences are positive when b is better.
        confidence: Level of the t interval of the mean difference.

    The Wilcoxon p-value is NaN with fewer than 6 non-zero differences (zeros are dropped, as
    scipy's default ``zero_method="wilcox"`` does): with 5 its exact two-sided p-value is at
    least 2/2⁵ = 0.0625, so it could never reject at 0.05; with none it is undefined.

    Raises:
        ConfigError: Lengths differ, fewer than 2 seeds, a non-finite value or a bad level.
    """
    x, y = _per_seed(a=a, b=b)
    _check_level("confidence", confidence)
    d = y - x if higher_is_better else x - y
    n, mean = d.size, float(np.mean(d))
    half = float(scipy.stats.t.ppf(0.5 + confidence / 2, n - 1) * np.std(d, ddof=1) / np.sqrt(n))
    with warnings.catch_warnings():
        # Differences all (nearly) equal: scipy warns of precision loss; t is then ±inf (p 0)
        # or undefined (p NaN, all 0), which the callers read as such.
        warnings.simplefilter("ignore", RuntimeWarning)
        p_t = float(scipy.stats.ttest_rel(y, x).pvalue)  # two-sided: either orientation
    nonzero, p_w = d[d != 0], np.nan
    if nonzero.size >= WILCOXON_MIN_N:
        # scipy's stubs type wilcoxon's result as an anonymous class without fields.
        p_w = float(scipy.stats.wilcoxon(nonzero).pvalue)  # pyright: ignore[reportAttributeAccessIssue]
    wins, losses = int(np.sum(d > 0)), int(np.sum(d < 0))
    return PairedTest(n, mean, (mean - half, mean + half), confidence, p_t, p_w, wins, losses)


def truth_gate(
    noisy: ArrayLike, truth: ArrayLike, *, higher_is_better: bool, alpha: float = 0.01
) -> Gate:
    """Pass when truth beats noisy: paired t-test p < ``alpha`` (two-sided), mean in its favour.

    If learners trained on the ground truth are not clearly better than those trained on noisy
    demos, the protocol cannot detect a benefit of cleaning, whatever the cleaner does.

    Args:
        noisy: Per-seed scores of the noisy-trained models, shape (S,).
        truth: Per-seed scores of the truth-trained models, shape (S,).
        higher_is_better: Orientation of the metric.
        alpha: Level of the gate (strict by default: it guards every later claim).
    """
    _check_level("alpha", alpha)
    test = paired(noisy, truth, higher_is_better=higher_is_better)
    passed = bool(test.p_t < alpha and test.mean_diff > 0)
    if passed:
        reason = f"truth beats noisy in {test.wins}/{test.n} seeds, {_p_text(test.p_t)}"
    else:
        what = "is worse than" if test.p_t < alpha else "does not clearly beat"
        reason = f"truth {what} noisy ({_p_text(test.p_t)}): " + _CANNOT_TELL
    return Gate(passed, test, alpha, reason)


def gap_share(
    noisy: ArrayLike,
    cleaned: ArrayLike,
    truth: ArrayLike,
    *,
    higher_is_better: bool,
    confidence: float = 0.95,
    resamples: int = 2000,
    seed: int = 0,
) -> GapShare:
    """Share of the truth-noisy gap recovered by cleaning, with a paired bootstrap interval.

    Each resample draws S seed indices with replacement, the same for the three arrays, and
    recomputes the ratio of means; the interval is the percentile interval of the resamples
    whose gap is > 0, NaN if more than (1 − confidence)/2 of them have none. Percentile
    intervals run somewhat narrow for S ≈ 10: read them as a guide.

    Args:
        noisy, cleaned, truth: Per-seed scores, shape (S,) each, S ≥ 2.
        higher_is_better: Orientation of the metric (the ratio does not depend on it; whether
            there is a gap does).
        confidence: Level of the interval.
        resamples: Bootstrap resamples (≥ 100).
        seed: Seed of the resampling; the result is deterministic given it.
    """
    x, c, y = _per_seed(noisy=noisy, cleaned=cleaned, truth=truth)
    _check_level("confidence", confidence)
    if resamples < 100:
        raise ConfigError(f"resamples is {resamples}; at least 100 are needed")
    sign = 1.0 if higher_is_better else -1.0
    gap = sign * float(np.mean(y) - np.mean(x))
    if gap <= 0:
        note = f"truth does not beat noisy on average (gap {gap:+.3g}): no gap to recover"
        return GapShare(np.nan, (np.nan, np.nan), confidence, gap, 1.0, note)
    share = float((np.mean(c) - np.mean(x)) / (np.mean(y) - np.mean(x)))
    idx = np.random.default_rng(seed).integers(0, x.size, size=(resamples, x.size))
    gaps = sign * (y[idx].mean(axis=1) - x[idx].mean(axis=1))  # (resamples,)
    defined = gaps > 0
    undefined, tail = float(1.0 - np.mean(defined)), (1.0 - confidence) / 2
    if undefined > tail:
        note = f"no gap in {undefined:.0%} of resamples: the interval is not defined"
        return GapShare(share, (np.nan, np.nan), confidence, gap, undefined, note)
    ratios = sign * (c[idx].mean(axis=1) - x[idx].mean(axis=1))[defined] / gaps[defined]
    lo, hi = np.quantile(ratios, [tail, 1.0 - tail])
    note = f"{undefined:.1%} of resamples had no gap and were left out" if undefined else ""
    return GapShare(share, (float(lo), float(hi)), confidence, gap, undefined, note)


def verdict(
    noisy: ArrayLike,
    cleaned: ArrayLike,
    truth: ArrayLike,
    *,
    higher_is_better: bool,
    alpha: float = 0.01,
    cleaned_alpha: float = 0.05,
) -> Verdict:
    """The gate, then cleaned vs noisy by the paired t-test (two-sided), and the gap share.

    Args:
        noisy, cleaned, truth: Per-seed scores, shape (S,) each, same seeds in the same order.
        higher_is_better: Orientation of the metric.
        alpha: Level of :func:`truth_gate`.
        cleaned_alpha: Level of the cleaned-vs-noisy test. Over many cells, adjust
            ``cleaned_vs_noisy.p_t`` with :func:`holm` before counting wins.
    """
    _per_seed(noisy=noisy, cleaned=cleaned, truth=truth)  # errors name the array at fault
    _check_level("cleaned_alpha", cleaned_alpha)
    gate = truth_gate(noisy, truth, higher_is_better=higher_is_better, alpha=alpha)
    test = paired(noisy, cleaned, higher_is_better=higher_is_better)
    gap = gap_share(noisy, cleaned, truth, higher_is_better=higher_is_better)
    outcome: Outcome = "no significant difference"
    if not gate.passed:
        outcome = "cannot tell"
    elif test.p_t < cleaned_alpha:
        outcome = "cleaned better" if test.mean_diff > 0 else "cleaned worse"
    return Verdict(outcome, gate, test, gap, cleaned_alpha)


def wilson(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a success probability, ``successes`` out of ``n`` trials.

    For the rollouts of *one* trained model: it bounds that model's success rate, not the spread
    over training seeds (compare datasets with :func:`paired` on per-seed rates).
    """
    if n < 1 or not 0 <= successes <= n:
        raise ConfigError(f"{successes} successes out of {n}; need n ≥ 1 and 0 ≤ successes ≤ n")
    _check_level("confidence", confidence)
    ci = scipy.stats.binomtest(successes, n).proportion_ci(confidence, method="wilson")
    return float(ci.low), float(ci.high)


def success_curve(distances_mm: ArrayLike, taus_mm: ArrayLike) -> FloatArray:
    """Share of rollouts whose distance is ≤ τ, for each threshold τ.

    Args:
        distances_mm: One scalar per rollout [mm], shape (R,), e.g. the worst distance from a
            reference point to the rollout; +inf is never within any τ.
        taus_mm: Thresholds τ [mm], shape (T,).

    Returns:
        Shares in [0, 1], shape (T,), non-decreasing in τ; ``round(share * R)`` successes out of
        R give :func:`wilson` intervals.
    """
    d = np.asarray(distances_mm, dtype=np.float64)
    taus = np.asarray(taus_mm, dtype=np.float64)
    if d.ndim != 1 or d.size == 0 or np.any(np.isnan(d)):
        raise ConfigError(f"distances_mm must be 1-D, non-empty, without NaN; got shape {d.shape}")
    if taus.ndim != 1 or not np.all(np.isfinite(taus)):
        raise ConfigError(f"taus_mm must be 1-D and finite; got shape {taus.shape}")
    return np.mean(d[None, :] <= taus[:, None], axis=1)


def holm(pvalues: ArrayLike) -> FloatArray:
    """Holm-Bonferroni adjusted p-values, shape (m,): the i-th smallest p times (m − i + 1),
    made monotone by a running maximum and capped at 1. NaN entries stay NaN and do not count
    in m. Cell i is rejected at family-wise level α when its adjusted p-value is < α."""
    p = np.asarray(pvalues, dtype=np.float64)
    if p.ndim != 1 or np.any((p < 0) | (p > 1)):
        raise ConfigError("pvalues must be 1-D with values in [0, 1] (NaN allowed)")
    out = np.full(p.shape, np.nan)
    valid = np.flatnonzero(~np.isnan(p))
    order = valid[np.argsort(p[valid], kind="stable")]
    scaled = p[order] * (order.size - np.arange(order.size))
    out[order] = np.minimum(np.maximum.accumulate(scaled), 1.0)
    return out


_CANNOT_TELL = "the protocol cannot tell whether cleaning helps here"


def _per_seed(**arrays: ArrayLike) -> list[FloatArray]:
    """Validated per-seed arrays: 1-D, finite, equal lengths ≥ 2; errors name the array."""
    out = [np.asarray(v, dtype=np.float64) for v in arrays.values()]
    for name, v in zip(arrays, out, strict=True):
        if v.ndim != 1:
            raise ConfigError(f"{name} must hold one value per seed, shape (S,); got {v.shape}")
        if bad := np.flatnonzero(~np.isfinite(v)).tolist():
            raise ConfigError(f"{name} has non-finite values at seeds {bad}; all must be finite")
    sizes = {name: v.size for name, v in zip(arrays, out, strict=True)}
    if len(set(sizes.values())) != 1:
        raise ConfigError(f"per-seed arrays must have equal lengths (same seeds); got {sizes}")
    if (n := out[0].size) < 2:
        raise ConfigError(f"{n} seed(s); at least 2 are needed (10 or more for a verdict)")
    return out


def _check_level(name: str, value: float) -> None:
    if not 0 < value < 1:
        raise ConfigError(f"{name} is {value}; it must lie strictly between 0 and 1")


def _p_text(p: float) -> str:
    if np.isnan(p):
        return "p undefined"
    return "p < 0.001" if p < 0.001 else f"p = {p:.2g}"
