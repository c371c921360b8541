"""The exact sign-flip test against enumerating every sign vector by hand."""

import itertools

import numpy as np
import pytest

from models.stats import EXACT_MAX_SEEDS, _signed_sums, sign_flip_p


def brute_force_p(d):
    d = np.asarray(d, float)
    means = [np.mean(d * np.array(s)) for s in itertools.product([1, -1], repeat=len(d))]
    return np.mean([abs(m) >= abs(d.mean()) - 1e-12 for m in means])


@pytest.mark.parametrize("n", [1, 2, 5, 9, 12])
def test_equals_enumerating_every_sign_vector(n):
    rng = np.random.default_rng(n)
    for d in (rng.normal(size=n), rng.integers(-2, 3, n).astype(float), np.round(rng.normal(size=n), 1)):
        assert sign_flip_p(d) == pytest.approx(brute_force_p(d), abs=1e-12)


def test_known_values():
    assert sign_flip_p([0.3]) == 1.0  # one seed: both signs are as extreme
    assert sign_flip_p([0.0, 0.0, 0.0]) == 1.0
    assert sign_flip_p([1.0] * 5) == 2 / 32  # all +, or all -
    assert sign_flip_p([1.0, -1.0, 1.0, -1.0]) == 1.0


def test_beyond_the_exact_limit_a_seeded_estimate_close_to_the_exact_value():
    rng = np.random.default_rng(0)
    d = rng.normal(0.4, 1.0, EXACT_MAX_SEEDS + 2)
    p = sign_flip_p(d)
    assert p == sign_flip_p(d)  # seeded: the same number every time
    # the exact value, from all 2^22 signed sums (two halves of 2^11 each)
    sums = (_signed_sums(d[:11])[:, None] + _signed_sums(d[11:])[None, :]).ravel()
    exact = np.mean(np.abs(sums) >= abs(d.sum()) - 1e-9)
    assert abs(p - exact) < 0.005


@pytest.mark.parametrize("bad", [[], [np.nan, 1.0], [[1.0, 2.0]]])
def test_bad_input_is_one_line(bad):
    with pytest.raises(ValueError, match="non-empty 1-d array of finite differences"):
        sign_flip_p(bad)
