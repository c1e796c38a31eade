import pytest

from goldenticket.stats import Rate, paired_exact_test, sign_test, wilson_interval


def test_wilson_known_value():
    low, high = wilson_interval(8, 10)
    assert low == pytest.approx(0.4902, abs=1e-4)
    assert high == pytest.approx(0.9433, abs=1e-4)


def test_wilson_all_and_none():
    # All successes: upper bound 1, lower bound n / (n + z^2).
    low, high = wilson_interval(10, 10)
    assert high == pytest.approx(1.0)
    assert low == pytest.approx(10 / (10 + 1.959964**2), abs=1e-6)
    low, high = wilson_interval(0, 10)
    assert low == pytest.approx(0.0)
    assert high == pytest.approx(1 - 10 / (10 + 1.959964**2), abs=1e-6)


def test_wilson_wider_at_higher_confidence():
    low95, high95 = wilson_interval(5, 20)
    low99, high99 = wilson_interval(5, 20, confidence=0.99)
    assert low99 < low95 < 0.25 < high95 < high99


@pytest.mark.parametrize("k, n", [(0, 0), (3, 2), (-1, 5)])
def test_wilson_rejects_bad_counts(k, n):
    with pytest.raises(ValueError):
        wilson_interval(k, n)


def pairs(both_win, ticket_only, base_only, both_fail):
    ticket = [True] * both_win + [True] * ticket_only + [False] * base_only + [False] * both_fail
    base = [True] * both_win + [False] * ticket_only + [True] * base_only + [False] * both_fail
    return ticket, base


@pytest.mark.parametrize(
    "b, c, expected",
    [
        (5, 0, 1 / 32),  # P(X >= 5), X ~ Bin(5, 1/2)
        (3, 1, 5 / 16),  # (4 + 1) / 16
        (1, 3, 15 / 16),  # 1 - P(X = 0)
        (6, 2, 37 / 256),  # (28 + 8 + 1) / 256
        (0, 2, 1.0),
    ],
)
def test_paired_exact_test_tail(b, c, expected):
    assert paired_exact_test(*pairs(7, b, c, 4)) == pytest.approx(expected)


def test_paired_concordant_pairs_do_not_matter():
    assert paired_exact_test(*pairs(0, 5, 0, 0)) == paired_exact_test(*pairs(40, 5, 0, 40))


def test_paired_no_discordant_pairs():
    assert paired_exact_test(*pairs(3, 0, 0, 2)) == 1.0
    assert paired_exact_test([], []) == 1.0


def test_paired_length_mismatch():
    with pytest.raises(ValueError, match="length"):
        paired_exact_test([True, False], [True])


def test_rate_of():
    rate = Rate.of([True] * 8 + [False] * 2)
    assert (rate.successes, rate.n, rate.success_rate) == (8, 10, 0.8)
    assert (rate.ci_low, rate.ci_high) == pytest.approx((0.4902, 0.9433), abs=1e-4)
    assert rate.to_dict() == {
        "success_rate": 0.8,
        "ci_low": rate.ci_low,
        "ci_high": rate.ci_high,
        "n": 10,
    }


def test_rate_all_success_and_empty():
    assert Rate.of([True] * 4).ci_high == pytest.approx(1.0)
    with pytest.raises(ValueError):
        Rate.of([])


@pytest.mark.parametrize("wins, losses, expected",
                         [(3, 0, 0.125), (0, 3, 1.0), (0, 0, 1.0), (9, 1, 11 / 1024)])
def test_sign_test_across_pairs(wins, losses, expected):
    assert sign_test(wins, losses) == pytest.approx(expected)
