"""The statistics of benchmarks/groups_ari_paired.py on a hand-computed 5-seed example:
d = a - b = (0.03, -0.01, 0.02, 0, 0.04)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import benchmarks.groups_ari_paired as gp

A = np.array([0.93, 0.89, 0.92, 0.90, 0.94])
B = np.full(5, 0.90)


def test_paired_t_and_counts_match_the_hand_computation():
    """mean 0.016; squared deviations sum to 1720e-6, so sd^2 = 430e-6 and SE = sqrt(86e-6);
    one-sided p of t with 4 degrees of freedom from the closed form
    P(T > t) = 1/2 - (sin th / 2)(1 + cos^2 th / 2), tan th = t / 2."""
    s = gp.paired_stats(A, B, "greater", n_boot=2000)
    se = math.sqrt(86e-6)
    t = 0.016 / se
    sin_th, cos2_th = t / math.sqrt(t * t + 4), 4 / (t * t + 4)
    assert s["n"] == 5 and (s["better"], s["worse"], s["equal"]) == (3, 1, 1)
    assert s["diff"] == pytest.approx(0.016, abs=1e-12)
    assert s["se"] == pytest.approx(se, rel=1e-9)
    assert s["t"] == pytest.approx(1.72532, abs=1e-5)
    assert s["p_t"] == pytest.approx(0.5 - sin_th / 2 * (1 + cos2_th / 2), rel=1e-9)
    assert s["p_t"] == pytest.approx(0.0798, abs=5e-4)


def test_wilcoxon_is_exact_over_the_nonzero_differences():
    """The zero is dropped; |d| ranks 1 (the -0.01), 2, 3, 4, so W+ = 9; of the 16 sign
    patterns only {2,3,4} (9) and {1,2,3,4} (10) reach 9: one-sided p = 2/16, two-sided 4/16."""
    assert gp.paired_stats(A, B, "greater", n_boot=10)["p_wilcoxon"] == pytest.approx(2 / 16)
    assert gp.paired_stats(A, B, "two-sided", n_boot=10)["p_wilcoxon"] == pytest.approx(4 / 16)
    assert gp.paired_stats(A, B, "less", n_boot=10)["p_wilcoxon"] == pytest.approx(15 / 16)


def test_a_seed_without_an_ari_is_dropped_from_both_sides():
    a, b = np.append(A, np.nan), np.append(B, 0.5)
    s = gp.paired_stats(a, b, "greater", n_boot=10)
    assert s["n"] == 5 and s["mean_b"] == pytest.approx(0.90)


def test_bootstrap_interval_is_seed_pinned_and_brackets_the_mean():
    d = A - B
    lo, hi = gp.bootstrap_ci(d, n_boot=4000, seed=0)
    assert (lo, hi) == gp.bootstrap_ci(d, n_boot=4000, seed=0)
    assert -0.01 <= lo < 0.016 < hi <= 0.04
    assert gp.bootstrap_ci(np.full(7, 0.002), n_boot=100) == pytest.approx((0.002, 0.002))


def test_pooled_t_from_a_summary_equals_the_union():
    """(5, 0.016, sqrt(86e-6)) pooled with (0.01, 0.01): 7 values, sum 0.10, sum of squares
    0.0032, so mean 1/70, sd^2 = (0.0032 - 0.01/7) / 6 and t = 2.1997."""
    s = gp.pooled_t(5, 0.016, math.sqrt(86e-6), np.array([0.01, 0.01]), "greater")
    var = (0.0032 - 0.01 / 7) / 6
    assert s["n"] == 7 and s["diff"] == pytest.approx(1 / 70, rel=1e-9)
    assert s["se"] == pytest.approx(math.sqrt(var / 7), rel=1e-9)
    assert s["t"] == pytest.approx(2.1997, abs=1e-4)
    union = gp.paired_stats(np.concatenate([A, [0.91, 0.91]]), np.full(7, 0.90), "greater", n_boot=10)
    assert s["p_t"] == pytest.approx(union["p_t"], rel=1e-9)


def test_csv_rows_read_back(tmp_path):
    p = tmp_path / "r.csv"
    p.write_text("seed,ari_a,ari_b,d2_a,d2_b\n121,0.9,0.8,0.3,0\n122,nan,0.7,0.2,0\n")
    rows = gp.read_rows(str(p))
    assert rows[0] == (121, 0.9, 0.8, 0.3, 0.0) and rows[1][0] == 122 and math.isnan(rows[1][1])
