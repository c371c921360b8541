"""The compiled per-decision pieces of the env and the rollout give the numbers of the numpy code they replaced, to the
bit (the state and reward: the recorded episodes of test_env.py)."""

import numpy as np
import torch

from models.urban import kernels
from models.urban.col_marl import RouteAgentsQ, numpy_params, q_values
from models.urban.env import _CAR_MPS2, _HEAVY_MPS2


def test_q_values_are_the_einsum_forward_to_the_bit():
    params = numpy_params(RouteAgentsQ(24, 6, torch.Generator().manual_seed(0)))
    rng = np.random.default_rng(0)
    for n in (1, 3, 5, 16, 150):  # fewer than four rows, four at a time and the rest (the Q layer's 5 outputs)
        states, agent = rng.normal(size=(n, 6)).astype(np.float32), rng.integers(0, 24, n)
        h = np.tanh(np.einsum("nd,ndh->nh", states, params["w1"][agent]) + params["b1"][agent])
        expected = np.einsum("nh,nha->na", h, params["w2"][agent]) + params["b2"][agent]
        q = q_values(params, states, agent)
        assert q.dtype == np.float32 and np.array_equal(q, expected)


def test_accelerations_are_np_clip_to_the_sign_of_zero():
    # holding (0 m/s²) at a standstill clips at -0 / ACTION_S = -0.0 under np.clip: SUMO was always told -0.0 there
    rng = np.random.default_rng(1)
    speed = rng.choice([0.0, 0.3, 20.0, 39.9, 40.0], 500)
    action, is_car = rng.integers(0, 5, 500), rng.random(500) < 0.5
    expected = np.clip(np.where(is_car, _CAR_MPS2[action], _HEAVY_MPS2[action]), -speed / 1.0, (40.0 - speed) / 1.0)
    got = kernels.accelerations(action, is_car, speed, _CAR_MPS2, _HEAVY_MPS2, 40.0, 1.0)
    assert np.array_equal(got, expected) and np.array_equal(np.signbit(got), np.signbit(expected))
    assert np.signbit(got[(speed == 0.0) & (action == 2)]).all()


def test_snapshot_columns_keep_an_overlapping_leader_as_a_leader():
    # getLeader's distance excludes the follower's minGap and goes below -minGap when two vehicles overlap: that
    # leader is at 0 m, not "no leader" (-1); no leader at all is -1 whatever the distance says
    rows = np.zeros((9, 4))
    rows[3], rows[4], rows[5] = 700.0, 350.0, [0, 1, 1, 0]  # fuel mg/s, density mg/ml, lane code
    rows[6], rows[7] = [1, 1, 1, 0], [-4.0, -1.0, 7.5, -1.0]  # leader?, getLeader's distance
    rows[0], rows[1] = [13.9, 0.0, 7.25, 3.5], [12.0, 40.0, 3.0, 70.0]  # speeds (their sum: the metrics' mean speed), positions
    code, _, length, fuel_mlps, leader_dist, speed_sum, fuel_sum = kernels.snapshot_columns(rows, np.array([50.0, 80.0]), 2.5)
    assert leader_dist.tolist() == [0.0, 1.5, 10.0, -1.0] and length.tolist() == [50.0, 80.0, 80.0, 50.0]
    assert fuel_mlps.tolist() == [2.0] * 4 and code.dtype == np.int64 and fuel_sum == 8.0 and speed_sum == rows[0].sum()


def test_numpy_sum_is_numpys_pairwise_sum_to_the_bit():
    # the episode's speed and fuel sums: numpy's order of additions (8 accumulators, halves above 128 values), not a
    # running sum, whatever the length (vehicles on the road) and with the sign of a zero sum
    rng = np.random.default_rng(2)
    lengths = [*range(0, 140), 255, 256, 257, 300, 1000, 4099]
    for n in lengths:
        a = rng.normal(size=n) * 10.0 ** rng.integers(-3, 9, n)  # wide magnitudes: another order rounds differently
        for x in (a, np.abs(a), -np.zeros(n)):
            expected = x.sum()
            assert kernels.numpy_sum(x) == expected and np.signbit(kernels.numpy_sum(x)) == np.signbit(expected), n
    a = rng.normal(size=300) * 10.0 ** rng.integers(-3, 9, 300)
    assert kernels.numpy_sum(a) != sum(a.tolist())  # a running sum is not numpy's: the test can tell


def _numpy_epsilon_greedy(rng, q, epsilon, allowed):
    """The rollout's ε-greedy choice as numpy expressions (what the kernel replaced)."""
    explore = rng.random(len(q)) < epsilon
    if allowed is None:
        return np.where(explore, rng.integers(0, q.shape[1], len(q)), q.argmax(axis=1))
    return np.where(explore, (rng.random(allowed.shape) * allowed).argmax(axis=1), np.where(allowed, q, -np.inf).argmax(axis=1))


def test_epsilon_greedy_draws_what_numpy_draws_and_leaves_the_generator_as_numpy_does():
    gen = np.random.default_rng(3)
    for seed in range(20):
        numpy_rng, kernel_rng = np.random.default_rng(seed), np.random.default_rng(seed)
        bitgen = kernels.bit_generator(kernel_rng)
        for k in range(60):
            n, n_actions = int(gen.integers(1, 30)), int(gen.choice([4, 5]))
            q = gen.normal(size=(n, n_actions)).astype(np.float32)
            q[:, 1] = q[:, 0] if k % 4 == 0 else q[:, 1]  # ties: the first
            q[gen.random(q.shape) < (0.2 if k % 5 == 0 else 0.0)] = np.nan  # numpy's argmax takes the first NaN
            allowed = gen.random((n, n_actions)) < 0.6 if k % 3 == 0 else None
            epsilon = float(gen.choice([0.0, 0.1, 0.5, 1.0]))
            expected = _numpy_epsilon_greedy(numpy_rng, q, epsilon, allowed)
            got = kernels.epsilon_greedy(q, epsilon, bitgen, allowed)
            assert got.dtype == expected.dtype and np.array_equal(got, expected), (seed, k)
            if k % 10 == 0:  # numpy's own draws in between go on from where the kernel's left the generator
                assert np.array_equal(numpy_rng.integers(0, 5, 7), kernel_rng.integers(0, 5, 7))
        assert numpy_rng.bit_generator.state == kernel_rng.bit_generator.state


def test_epsilon_greedy_redraws_as_numpy_does_draws_nothing_for_one_action_and_takes_any_bit_generator():
    # numpy's Lemire method draws again when a draw's low 32 bits fall under its threshold: about once in 2**32 draws
    # for 5 actions, so the test above never sees it; with 3 * 2**30 actions (a zero-stride view: nothing allocated) a
    # quarter of the draws are redrawn (2**31 actions: none, a threshold of 0). One action draws nothing; MT19937 as
    # well as PCG64
    for bits in (np.random.PCG64, np.random.MT19937):
        numpy_rng, kernel_rng = np.random.Generator(bits(11)), np.random.Generator(bits(11))
        bitgen = kernels.bit_generator(kernel_rng)
        for width in (3 * 2**30, 2**31):
            wide = np.lib.stride_tricks.as_strided(np.zeros(1, np.float32), shape=(64, width), strides=(0, 0))
            assert (numpy_rng.random(64) < 1.0).all()  # ε = 1: every row explores
            assert np.array_equal(kernels.epsilon_greedy(wide, 1.0, bitgen, None), numpy_rng.integers(0, width, 64))
        q = np.random.default_rng(0).normal(size=(40, 1)).astype(np.float32)
        assert np.array_equal(kernels.epsilon_greedy(q, 0.5, bitgen, None), _numpy_epsilon_greedy(numpy_rng, q, 0.5, None))
        assert np.array_equal(numpy_rng.random(3), kernel_rng.random(3))  # the generators in the same state
