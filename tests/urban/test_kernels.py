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
    for n in (1, 3, 16, 150):
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
    code, _, length, fuel_mlps, leader_dist = kernels.snapshot_columns(rows, np.array([50.0, 80.0]), 2.5)
    assert leader_dist.tolist() == [0.0, 1.5, 10.0, -1.0] and length.tolist() == [50.0, 80.0, 80.0, 50.0]
    assert fuel_mlps.tolist() == [2.0] * 4 and code.dtype == np.int64
