"""Chapter 3's variant on real SUMO: collision matrix, speed actions, Eq 3.2-3.4, training and acting."""

import numpy as np
import pytest
import torch

from models.urban import cnn_marl
from models.urban.cnn_marl import CONFLICT, GRID, PATH, Ch3Env, collision_matrix
from models.urban.col_marl import EpisodeJob, run_episode, train
from models.parallel import ProcessPool
from urban_fixtures import crossing_copy, make_copy


def test_collision_matrix_marks_the_ego_path_and_a_predicted_conflict():
    # junction 0 at the origin, half-size 10 m; ego 0 drives east along y = 1, vehicle 1 north along x = 1
    centre, half = np.zeros((1, 2)), np.array([10.0])
    entry = np.array([[-10.0, 1.0], [1.0, -10.0], [0.0, 0.0]])
    exit_ = np.array([[10.0, 1.0], [1.0, 10.0], [0.0, 0.0]])
    direction = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 0.0]])
    xy = entry - direction * 20.0  # both 20 m before the junction
    speed = np.array([10.0, 10.0, 10.0])
    m = collision_matrix(np.array([0, 0, -1]), entry, exit_, xy, direction, np.array([20.0, 20.0, 0.0]), speed, centre, half)
    assert m.shape == (3, GRID, GRID)
    assert (m[0] == CONFLICT).sum() >= 1 and (m[0] == PATH).sum() >= 3  # same arrival time: the crossing cell is -5
    assert (m[0] > 0).sum() >= 1  # vehicle 1's other cells count its predicted visits
    assert not m[2].any()  # no junction ahead: empty matrix
    slow = collision_matrix(np.array([0, 0, -1]), entry, exit_, xy, direction, np.array([20.0, 20.0, 0.0]),
                            np.array([10.0, 2.0, 10.0]), centre, half)
    assert (slow[0] == CONFLICT).sum() == 0 and (slow[0] == PATH).sum() >= 3  # vehicle 1 arrives much later


def test_reward_eq_3_2_and_3_3():
    r = cnn_marl.reward(np.array([15.0, 15.0, 15.0, 15.0]), np.array([-1.0, -1.0, 30.0, 30.0]), np.array([False, True, False, True]))
    assert r == pytest.approx([3 * 0.5, -3 * 0.5, -(1 + 0.5) * 20.0, -(2 + 0.5) * 20.0])


def test_speed_actions_reach_their_target_and_a_forced_crossing_collides(tmp_path, sc1_net):
    env = Ch3Env(crossing_copy(tmp_path / "cross", sc1_net))
    obs, _ = env.reset(seed=0)
    assert env.action_space(None).n == 4 and all(o.shape == (cnn_marl.STATE_DIM,) for o in obs.values())
    assert all((o[4:] == CONFLICT).any() for o in obs.values())  # same distance and speed: predicted to collide
    speeds = []
    while env.agents:
        env.step({a: 0 for a in env.agents})  # 15 m/s for both: they meet in the junction
        speeds += [env.sim.ls.vehicle.getSpeed(v) for v in env.agents]
    tally = env.sim.tally
    env.close()
    assert len(tally.collision_pairs) == 1
    assert max(speeds) == pytest.approx(15.0, abs=0.01)  # entry 10 m/s, then held at the chosen 15 m/s


def test_ch3_trains_and_acts(tmp_path, sc1_net):
    files, routes = make_copy(tmp_path / "c", sc1_net, 15, 60.0)
    agents = [f"{r['route_id']}:{c}" for r in routes for c in ("car", "heavy")]
    with ProcessPool(1, run_episode) as pool:
        params, rows = train([(files, 15)], agents, "ch3", 2, 0, pool, log=lambda _: None)
    assert params["p.c_w"].shape == (len(agents), 9, cnn_marl.CNN_FILTERS) and params["p.d_w1"].shape == (len(agents), 4, 100)
    assert np.isfinite([r["loss"] for r in rows]).any()
    result = run_episode(EpisodeJob(files, "ch3", agents, params, 0.0, 3, 15))
    t = result.transitions
    assert t["state"].shape[1] == cnn_marl.STATE_DIM and set(np.unique(t["action"])) <= {0, 1, 2, 3}
    assert result.metrics["arrived"] + 2 * result.metrics["collisions"] + result.metrics["teleports"] >= 15
    q = cnn_marl.RouteAgentsDQNCNN(len(agents), cnn_marl.STATE_DIM, torch.Generator().manual_seed(0))
    x = torch.from_numpy(t["state"][:5])[None].repeat(len(agents), 1, 1)
    assert q(x).shape == (len(agents), 5, 4)


def test_cnn_branch_is_a_3x3_convolution_and_2x2_max_pool_per_agent():
    # the batched matrix-product convolution must equal torch's conv2d + max_pool2d with each agent's own filters
    n_agents, batch = 3, 7
    q = cnn_marl.RouteAgentsDQNCNN(n_agents, cnn_marl.STATE_DIM, torch.Generator().manual_seed(1))
    p = {k: v.detach() for k, v in q.p.items()}
    x = torch.randn(n_agents, batch, cnn_marl.STATE_DIM, generator=torch.Generator().manual_seed(2))
    got = q(x).detach()
    for a in range(n_agents):
        grid = x[a, :, cnn_marl.INDIVIDUAL_DIM:].reshape(batch, 1, GRID, GRID)
        w = p["c_w"][a].T.reshape(cnn_marl.CNN_FILTERS, 1, cnn_marl.CNN_KERNEL, cnn_marl.CNN_KERNEL)
        pooled = torch.nn.functional.max_pool2d(torch.relu(torch.nn.functional.conv2d(grid, w, p["c_b"][a])), 2)
        q2 = torch.relu(pooled.permute(0, 2, 3, 1).reshape(batch, -1) @ p["c_w1"][a] + p["c_b1"][a]) @ p["c_w2"][a] + p["c_b2"][a]
        s1 = x[a, :, : cnn_marl.INDIVIDUAL_DIM]
        q1 = torch.relu(s1 @ p["d_w1"][a] + p["d_b1"][a]) @ p["d_w2"][a] + p["d_b2"][a]
        torch.testing.assert_close(got[a], cnn_marl.MU * q1 + (1 - cnn_marl.MU) * q2, rtol=1e-5, atol=1e-5)
