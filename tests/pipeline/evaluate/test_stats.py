"""The statistics of the cleaned-vs-noisy verdict, against hand-computed and textbook values."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from bt_pipeline.evaluate.stats import (
    gap_share,
    holm,
    paired,
    success_curve,
    truth_gate,
    verdict,
    wilson,
)
from bt_pipeline.exceptions import ConfigError

SEEDS = 10


def _noise(seed: int, scale: float, *, zero_mean: bool = False) -> np.ndarray:
    """Per-seed noise, shape (SEEDS,); ``zero_mean`` removes its sample mean exactly."""
    e = np.random.default_rng(seed).normal(0.0, scale, SEEDS)
    return e - e.mean() if zero_mean else e


NOISY = 0.4 + _noise(1, 0.1)


def test_paired_matches_hand_values_and_scipy() -> None:
    a = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    b = np.array([2.0, 4.0, 3.0, 3.0, 8.0])  # d = b − a = (1, 2, 0, −1, 3): mean 1, sd √2.5
    t = paired(a, b, higher_is_better=True)
    assert t.n == 5 and t.mean_diff == pytest.approx(1.0)
    # By hand: 1 ± t_{0.975, 4} · √2.5/√5 = 1 ± 2.776445 / √2 (t table: 2.776).
    assert t.ci == pytest.approx((-0.963243, 2.963243), abs=1e-5)
    assert t.p_t == pytest.approx(scipy.stats.ttest_rel(b, a).pvalue)
    assert t.p_t == pytest.approx(0.2302, abs=1e-4)  # t = √2 on 4 degrees of freedom
    assert (t.wins, t.losses) == (3, 1)
    assert np.isnan(t.p_wilcoxon)  # 4 non-zero differences: too few

    low = paired(a, b, higher_is_better=False)  # now smaller is better: b is worse on average
    assert low.mean_diff == pytest.approx(-1.0)
    assert low.ci == pytest.approx((-2.963243, 0.963243), abs=1e-5)
    assert (low.wins, low.losses) == (1, 3)
    assert low.p_t == pytest.approx(t.p_t)


def test_paired_wilcoxon_exact_value() -> None:
    a = np.zeros(7)
    b = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 0.0])  # six positive differences and one zero
    # All six signs positive: exact two-sided p = 2 / 2⁶.
    assert paired(a, b, higher_is_better=True).p_wilcoxon == pytest.approx(2 / 64)
    assert np.isnan(paired(a, a, higher_is_better=True).p_wilcoxon)  # all differences zero


@pytest.mark.parametrize(
    ("a", "b", "message"),
    [
        ([1.0, 2.0, 3.0], [1.0, 2.0], "equal lengths"),
        ([1.0], [2.0], "at least 2"),
        ([1.0, 2.0], [1.0, np.nan], "b has non-finite values at seeds [1]"),
        ([[1.0, 2.0]], [[1.0, 2.0]], "one value per seed"),
    ],
)
def test_paired_rejects_bad_input(a: list, b: list, message: str) -> None:
    with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("]", r"\]")):
        paired(a, b, higher_is_better=True)


def test_truth_gate_passes_on_separated_and_fails_on_overlapping() -> None:
    clear = truth_gate(NOISY, NOISY + 1.0 + _noise(2, 0.1), higher_is_better=True)
    assert clear.passed and clear.test.p_t < 0.01
    assert clear.reason.startswith("truth beats noisy in 10/10 seeds, p")

    overlap = truth_gate(NOISY, NOISY + _noise(3, 0.1, zero_mean=True), higher_is_better=True)
    assert not overlap.passed and overlap.test.p_t > 0.9
    assert "does not clearly beat" in overlap.reason and "cannot tell" in overlap.reason

    # A distance in mm: truth is better when it is smaller.
    lower = truth_gate(NOISY + 1.0, NOISY + _noise(2, 0.1), higher_is_better=False)
    assert lower.passed
    wrong_way = truth_gate(NOISY + 1.0, NOISY + _noise(2, 0.1), higher_is_better=True)
    assert not wrong_way.passed and "is worse than" in wrong_way.reason


def test_gap_share_halfway_is_one_half_with_a_narrow_interval() -> None:
    truth = NOISY + 1.0 + _noise(2, 0.1)
    cleaned = (NOISY + truth) / 2 + _noise(4, 0.01, zero_mean=True)
    g = gap_share(NOISY, cleaned, truth, higher_is_better=True)
    assert g.share == pytest.approx(0.5)
    assert g.ci[0] < 0.5 < g.ci[1] and g.ci[1] - g.ci[0] < 0.05
    assert g.undefined == 0.0 and g.note == ""

    noisier = gap_share(NOISY, cleaned + _noise(5, 0.3), truth, higher_is_better=True)
    assert noisier.ci[1] - noisier.ci[0] > 5 * (g.ci[1] - g.ci[0])

    assert gap_share(NOISY, cleaned, truth, higher_is_better=True, seed=0) == g  # deterministic
    assert gap_share(NOISY, cleaned, truth, higher_is_better=True, seed=1).ci != g.ci

    # Negating every score and the orientation changes nothing.
    flipped = gap_share(-NOISY, -cleaned, -truth, higher_is_better=False)
    assert flipped.share == pytest.approx(0.5) and flipped.ci == pytest.approx(g.ci)


def test_gap_share_without_a_gap_is_nan_with_a_note() -> None:
    g = gap_share(NOISY, NOISY + 0.1, NOISY - 0.2, higher_is_better=True)
    assert np.isnan(g.share) and np.isnan(g.ci).all() and g.gap == pytest.approx(-0.2)
    assert "no gap to recover" in g.note

    # A small mean gap with a large spread: the gap vanishes in many resamples.
    swing = np.tile([1.0, -1.0], SEEDS // 2) + 0.05
    shaky = gap_share(NOISY, NOISY, NOISY + swing, higher_is_better=True)
    assert shaky.share == pytest.approx(0.0, abs=1e-12) and np.isnan(shaky.ci).all()
    assert shaky.undefined > 0.025 and "not defined" in shaky.note


@pytest.mark.parametrize(
    ("cleaned_shift", "truth_shift", "outcome"),
    [
        (0.5, 1.0, "cleaned better"),
        (-0.5, 1.0, "cleaned worse"),
        (0.0, 1.0, "no significant difference"),
        (0.5, 0.0, "cannot tell"),
    ],
)
def test_verdict_outcomes(cleaned_shift: float, truth_shift: float, outcome: str) -> None:
    cleaned = NOISY + cleaned_shift + _noise(6, 0.1, zero_mean=True)
    truth = NOISY + truth_shift + _noise(7, 0.1, zero_mean=True)
    for higher in (True, False):
        sign = 1.0 if higher else -1.0  # a lower-is-better metric: the same data, negated
        v = verdict(sign * NOISY, sign * cleaned, sign * truth, higher_is_better=higher)
        assert v.outcome == outcome
        assert v.summary().startswith(f"{outcome}:")
    if outcome == "cleaned better":
        assert "recovers 50% of the truth-noisy gap" in v.summary()
    if outcome == "cannot tell":
        assert "does not clearly beat" in v.summary()


def test_wilson_textbook_values() -> None:
    # Wilson score intervals at z = 1.96: 0/10 upper = z²/(n + z²); 5/10 = 0.5 ± 0.2634.
    assert wilson(5, 10) == pytest.approx((0.2366, 0.7634), abs=1e-4)
    assert wilson(0, 10) == pytest.approx((0.0, 0.2775), abs=1e-4)
    assert wilson(10, 10) == pytest.approx((0.7225, 1.0), abs=1e-4)
    with pytest.raises(ConfigError, match="successes"):
        wilson(11, 10)


def test_success_curve_counts_rollouts_within_each_threshold() -> None:
    shares = success_curve([1.0, 2.0, 3.0, np.inf], [0.5, 1.0, 2.5, 10.0])
    np.testing.assert_allclose(shares, [0.0, 0.25, 0.5, 0.75])
    with pytest.raises(ConfigError, match="NaN"):
        success_curve([1.0, np.nan], [1.0])


def test_holm_worked_example() -> None:
    # Sorted 0.005, 0.01, 0.03, 0.04 times 4, 3, 2, 1 = 0.02, 0.03, 0.06, 0.04 → running max.
    np.testing.assert_allclose(holm([0.01, 0.04, 0.03, 0.005]), [0.03, 0.06, 0.06, 0.02])
    np.testing.assert_allclose(holm([0.5, 0.6]), [1.0, 1.0])  # capped at 1
    np.testing.assert_allclose(holm([0.01, np.nan, 0.04]), [0.02, np.nan, 0.04])
    assert holm([]).shape == (0,)
    with pytest.raises(ConfigError, match=r"\[0, 1\]"):
        holm([0.5, 1.5])


def test_paired_ignores_what_each_seed_adds_to_both_and_welch_does_not() -> None:
    """A seed's own effect (its set, starts and training luck) moves noisy and cleaned alike;
    the paired test over seeds is blind to it, Welch's test between the datasets is not. Here
    cleaned is better by 0.05 in every seed: paired that is clear whatever the seed effects, and
    Welch loses it once they are large. So a verdict made with Welch would fail this test."""
    gain = 0.05 + _noise(8, 0.005)
    base = paired(NOISY, NOISY + gain, higher_is_better=True)
    assert base.p_t < 1e-6 and base.wins == SEEDS
    for scale in (0.1, 1.0, 10.0):
        seed_effect = _noise(9, scale)
        a, b = NOISY + seed_effect, NOISY + gain + seed_effect
        moved = paired(a, b, higher_is_better=True)
        assert moved.p_t == pytest.approx(base.p_t, rel=1e-6)
        assert moved.mean_diff == pytest.approx(base.mean_diff)
    welch = scipy.stats.ttest_ind(b, a, equal_var=False)
    assert welch.pvalue > 0.5  # pyright: ignore[reportAttributeAccessIssue]  # not in the stub
