"""col-MARL / i-MARL training on real SUMO episodes: seeded determinism, learning signal, per-agent isolation."""

import re
from pathlib import Path

import numpy as np
import pytest
import torch

from models.urban import col_marl
from models.urban.col_marl import EpisodeJob, ReplayBuffers, RouteAgentsQ, dqn_update, kit, run_episode, share_untrained, train
from models.urban.env import route_agent
from models.parallel import ProcessPool
from urban_fixtures import make_copy


def _train(files, agents, variant, seed, episodes=3, gradient_steps=None, shield=False, log=lambda _: None, **checkpoint):
    with ProcessPool(1, run_episode) as pool:
        return train([(files, 15)], agents, variant, episodes, seed, pool, log, gradient_steps=gradient_steps, shield=shield, **checkpoint)


def _drove(files, agents) -> np.ndarray:
    """Which route agents have a vehicle in the copy (the others never train)."""
    drove = {route_agent(v) for v in re.findall(r'<vehicle id="([^"]+)"', Path(files.routes).read_text())}
    return np.array([a in drove for a in agents])


def test_same_seed_same_policy_and_log(tmp_path, sc1_net, monkeypatch):
    files, routes = make_copy(tmp_path / "c", sc1_net, 15, 60.0)
    agents = [f"{r['route_id']}:{c}" for r in routes for c in ("car", "heavy")]
    (pa, ra), (pb, rb) = (_train(files, agents, "col", 0, gradient_steps=10) for _ in range(2))  # 10 steps: faster, same code path
    assert all(np.array_equal(pa[k], pb[k]) for k in pa)
    np.testing.assert_array_equal([r["loss"] for r in ra], [r["loss"] for r in rb])  # NaN == NaN here
    pc, _ = _train(files, agents, "col", 1, gradient_steps=10)
    assert not np.array_equal(pa["w1"], pc["w1"])
    assert {r["episode"] for r in ra} == {0, 1, 2} and len(ra) == 3 * len(agents)
    assert ra[0]["epsilon"] == 0.9 and ra[-1]["epsilon"] < 0.9
    # a long run logs every k-th episode and the last (k = episodes // LOG_EPISODES): the same rows, the same policy
    monkeypatch.setattr(col_marl, "LOG_EPISODES", 1)
    pt, rt = _train(files, agents, "col", 0, gradient_steps=10)
    assert all(np.array_equal(pa[k], pt[k]) for k in pa)
    kept = [r for r in ra if r["episode"] in (0, 2)]
    assert [(r["agent"], r["episode"]) for r in rt] == [(r["agent"], r["episode"]) for r in kept]
    np.testing.assert_array_equal([(r["return"], r["loss"]) for r in rt], [(r["return"], r["loss"]) for r in kept])


def _assert_same_rows(a: list[dict], b: list[dict]) -> None:
    assert [(r["agent"], r["episode"], r["epsilon"]) for r in a] == [(r["agent"], r["episode"], r["epsilon"]) for r in b]
    np.testing.assert_array_equal([(r["return"], r["loss"]) for r in a], [(r["return"], r["loss"]) for r in b])  # NaN == NaN here


def test_an_interrupted_run_resumes_from_its_checkpoint_to_the_uninterrupted_result(tmp_path, sc1_net):
    files, routes = make_copy(tmp_path / "c", sc1_net, 15, 60.0)
    agents = [f"{r['route_id']}:{c}" for r in routes for c in ("car", "heavy")]
    straight, straight_rows = _train(files, agents, "col", 0, episodes=4, gradient_steps=5)
    ckpt = tmp_path / "run.ckpt"

    def crash_in_third_episode(message):  # one worker: a round is one episode; the last checkpoint is after episode 2
        if "episode 3/4" in message:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _train(files, agents, "col", 0, episodes=4, gradient_steps=5, log=crash_in_third_episode, checkpoint_path=ckpt, checkpoint_every_s=0)
    log = []
    params, rows = _train(files, agents, "col", 0, episodes=4, gradient_steps=5, log=log.append, checkpoint_path=ckpt, checkpoint_every_s=0)
    assert any("resumed at episode 2/4" in m for m in log) and not any("episode 1/4" in m for m in log)
    assert all(np.array_equal(straight[k], params[k]) for k in straight)
    _assert_same_rows(rows, straight_rows)
    # finished: the checkpoint now holds the result, and a re-run returns it without an episode
    log.clear()
    again, again_rows = _train(files, agents, "col", 0, episodes=4, gradient_steps=5, log=log.append, checkpoint_path=ckpt)
    assert log == [f"col: trained already ({ckpt})"] and all(np.array_equal(params[k], again[k]) for k in params)
    _assert_same_rows(again_rows, rows)
    # another configuration (episodes) or an unreadable file: not used, the run starts afresh
    for damage in (lambda: None, lambda: ckpt.write_bytes(ckpt.read_bytes()[:100])):
        damage()
        log.clear()
        _, other_rows = _train(files, agents, "col", 0, episodes=2, gradient_steps=5, log=log.append, checkpoint_path=ckpt)
        assert "starting afresh" in log[0] and {r["episode"] for r in other_rows} == {0, 1}


def test_a_route_agent_that_saw_no_vehicle_drives_with_its_routes_trained_agent(tmp_path, sc1_net):
    # an agent with no vehicle in the training copies keeps its random initial weights, yet drives its route's vehicles of
    # its class on other copies (demo Sc1: 3 heavy agents held their vehicles at a standstill until SUMO teleported them)
    files, routes = make_copy(tmp_path / "c", sc1_net, 15, 60.0)
    agents = [f"{r['route_id']}:{c}" for r in routes for c in ("car", "heavy")]
    drove = _drove(files, agents)
    params, _ = _train(files, agents, "col", 0, episodes=2, gradient_steps=2)
    initial = {k: v.numpy() for k, v in RouteAgentsQ(len(agents), 6, torch.Generator().manual_seed(0)).state_dict().items()}
    shared = alone = 0
    for k, a in enumerate(agents):
        peers = [j for j, b in enumerate(agents) if drove[j] and b.rpartition(":")[0] == a.rpartition(":")[0]]
        if drove[k]:
            assert not np.array_equal(params["w2"][k], initial["w2"][k])  # trained: no longer its initial weights
        elif peers:
            assert all(np.array_equal(params[n][k], params[n][peers[0]]) for n in params)
            shared += 1
        else:  # no trained agent on its route: left as it was
            assert all(np.array_equal(params[n][k], initial[n][k]) for n in params)
            alone += 1
    assert shared and alone  # this copy has both cases
    # the first trained agent of the route, whatever the class order; nothing to share from: unchanged
    w = {"w": np.arange(5.0)[:, None]}
    got = share_untrained(w, ["r0:car", "r0:heavy", "r1:heavy", "r1:car", "r2:car"], np.array([False, True, False, False, False]))
    np.testing.assert_array_equal(got["w"][:, 0], [1, 1, 2, 3, 4])


def test_training_under_the_safety_layer_acts_and_bootstraps_within_the_masks(tmp_path, sc1_net, monkeypatch):
    files, routes = make_copy(tmp_path / "c", sc1_net, 15, 60.0)
    agents = [f"{r['route_id']}:{c}" for r in routes for c in ("car", "heavy")]
    params = {k: v.detach().numpy().copy() for k, v in RouteAgentsQ(len(agents), 6, torch.Generator().manual_seed(0)).state_dict().items()}
    masked_somewhere = False
    for eps in (1.0, 0.0):  # exploring draws among the allowed actions, greedy takes the best allowed one
        t = run_episode(EpisodeJob(files, "col", agents, params, eps, 3, 15, shield=True)).transitions
        assert len(t["action"]) and t["allowed"][np.arange(len(t["action"])), t["action"]].all()
        assert t["next_allowed"].shape == t["allowed"].shape and not np.array_equal(t["next_allowed"], t["allowed"])
        masked_somewhere |= not t["allowed"].all()
    assert masked_somewhere  # the layer did forbid actions: the check above could have failed
    masks_seen = []  # what the learner's updates were given as the next states' allowed actions
    real_update = col_marl.dqn_update
    monkeypatch.setattr(col_marl, "dqn_update", lambda q, opt, batch, threads=1: masks_seen.append(batch[7]) or real_update(q, opt, batch, threads))
    (free, _), (shielded, rows) = (_train(files, agents, "col", 0, episodes=2, gradient_steps=2, shield=s) for s in (False, True))
    assert not np.array_equal(free["w1"], shielded["w1"])  # masked actions: other transitions, other weights
    assert len(rows) == 2 * len(agents)
    assert masks_seen[:4] == [None] * 4 and all(m is not None for m in masks_seen[4:]) and not all(bool(m.all()) for m in masks_seen[4:])


def test_masked_bootstrap_takes_the_best_allowed_next_action():
    # double DQN under masks: y = r + γ Q_target(s', a*), a* = the online network's best *allowed* action in s'. Each row
    # allows two actions, neither the online network's overall best; the target network prefers the other one of the two
    n, b = 2, 6
    g = torch.Generator().manual_seed(0)
    batch = [torch.rand(n, b, 6, generator=g), torch.randint(0, 5, (n, b), generator=g), torch.rand(n, b, generator=g),
             torch.rand(n, b, 6, generator=g), torch.rand(n, b, 5, generator=g), torch.zeros(n, b), torch.tensor([True, True])]
    q = RouteAgentsQ(n, 6, torch.Generator().manual_seed(1))
    with torch.no_grad():
        q_taken = q(batch[0]).gather(2, batch[1][..., None]).squeeze(2)
        ranked = q(batch[3]).argsort(dim=2, descending=True)
    greedy, best_allowed, other = ranked[..., 0], ranked[..., 1], ranked[..., 2]
    allowed = torch.zeros(n, b, 5, dtype=torch.bool).scatter(2, ranked[..., 1:3], True)
    batch[4].scatter_(2, best_allowed[..., None], 0.0).scatter_(2, other[..., None], 2.0)  # the target's choice would be `other`
    losses = [dqn_update(q, torch.optim.SGD(q.parameters(), lr=0.0), (*batch, mask)) for mask in (allowed, None)]
    for pick, loss in zip((best_allowed, greedy), losses):
        y = batch[2] + col_marl.GAMMA * batch[4].gather(2, pick[..., None]).squeeze(2)
        np.testing.assert_allclose(loss, ((q_taken - y) ** 2).mean(dim=1).numpy(), rtol=1e-5)
    assert not np.allclose(losses[0], losses[1])


def test_masked_replay_buffers_keep_each_next_state_with_its_mask():
    # the masks ride along with their transitions through the ring (agent 0's wraps) and the sampling
    buffers = ReplayBuffers(3, 6, size=10, n_actions=5, masked=True)
    target, rng = RouteAgentsQ(3, 6, torch.Generator().manual_seed(0)), np.random.default_rng(0)
    for n in (7, 9):
        agent, next_state = np.array([0] * (n - 2) + [2, 2]), rng.random((n, 6), np.float32)
        buffers.add({"agent_idx": agent, "state": rng.random((n, 6), np.float32), "action": rng.integers(0, 5, n), "reward": rng.random(n, np.float32),
                     "next_state": next_state, "done": np.zeros(n, np.float32), "next_allowed": next_state[:, :5] > 0.5}, target)
    *batch, has_data, mask = buffers.sample(rng, 50)
    assert has_data.tolist() == [True, False, True]
    torch.testing.assert_close(mask[[0, 2]], batch[3][[0, 2], :, :5] > 0.5)
    assert ReplayBuffers(3, 6, size=10, n_actions=5).sample(rng, 4)[-1] is None


def test_i_marl_sees_four_state_terms(tmp_path, sc1_net):
    files, routes = make_copy(tmp_path / "c", sc1_net, 15, 60.0)
    agents = [f"{r['route_id']}:{c}" for r in routes for c in ("car", "heavy")]
    params, rows = _train(files, agents, "ind", 0, episodes=2, gradient_steps=2)  # shapes only: few steps
    assert params["w1"].shape == (len(agents), 4, 128)
    assert any(np.isfinite(r["return"]) for r in rows)


def test_each_route_agent_learns_only_from_its_own_data():
    gen = torch.Generator().manual_seed(0)
    q = RouteAgentsQ(3, 6, gen)
    before = {k: v.detach().clone() for k, v in q.state_dict().items()}
    opt = torch.optim.Adam(q.parameters(), lr=1e-3)
    n = 8
    batch = (torch.rand(3, n, 6), torch.randint(0, 5, (3, n)), torch.rand(3, n), torch.rand(3, n, 6), torch.rand(3, n, 5), torch.zeros(3, n),
             torch.tensor([True, False, True]), None)
    loss = dqn_update(q, opt, batch)
    assert np.isnan(loss[1]) and np.isfinite(loss[0])
    after = q.state_dict()
    assert torch.equal(after["w1"][1], before["w1"][1])  # agent 1 had no data: untouched
    assert not torch.equal(after["w1"][0], before["w1"][0])


def test_gradient_steps_per_episode_are_configurable(tmp_path, sc1_net):
    assert kit("col").gradient_steps == kit("ind").gradient_steps == 40 and kit("ch3").gradient_steps == 10
    files, routes = make_copy(tmp_path / "c", sc1_net, 15, 60.0)
    agents = [f"{r['route_id']}:{c}" for r in routes for c in ("car", "heavy")]
    (one, _), (default, _) = _train(files, agents, "col", 0, episodes=1, gradient_steps=1), _train(files, agents, "col", 0, episodes=1)
    init = RouteAgentsQ(len(agents), 6, torch.Generator().manual_seed(0)).w1.detach().numpy()
    # one Adam step moves each trained weight by about lr; 40 steps move them further (the agents with no vehicle only
    # take their route's trained agent's weights: left out)
    trained = _drove(files, agents)
    assert np.abs(default["w1"] - init)[trained].max() > 5 * np.abs(one["w1"] - init)[trained].max() > 0


def test_stacked_q_is_the_tanh_network_and_chunked_gradients_equal_one_pass(monkeypatch):
    gen = torch.Generator().manual_seed(0)
    q = RouteAgentsQ(5, 6, gen)
    x = torch.rand(5, 7, 6)
    p = {k: v.detach().double() for k, v in q.state_dict().items()}
    reference = torch.tanh(x.double() @ p["w1"] + p["b1"][:, None]) @ p["w2"] + p["b2"][:, None]  # §4.3.1's tanh layer
    torch.testing.assert_close(q(x).double(), reference, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(q(x[1:3], slice(1, 3)), q(x)[1:3])
    batch = (x, torch.randint(0, 5, (5, 7)), torch.rand(5, 7), torch.rand(5, 7, 6), torch.rand(5, 7, 5), torch.zeros(5, 7),
             torch.tensor([True, True, False, True, True]), None)
    grads, losses = [], []
    for rows in (10**6, 14):  # one pass over the stack, then 2 agents per pass
        monkeypatch.setattr(col_marl, "CHUNK_ROWS", rows)
        net = RouteAgentsQ(5, 6, torch.Generator().manual_seed(0))
        losses.append(dqn_update(net, torch.optim.SGD(net.parameters(), lr=0.0), batch))
        grads.append({k: v.grad.clone() for k, v in net.named_parameters()})
    np.testing.assert_allclose(losses[0], losses[1], rtol=1e-6)
    for k in grads[0]:
        torch.testing.assert_close(grads[0][k], grads[1][k])
    assert np.isnan(losses[0][2]) and not grads[0]["w1"][2].any()


def test_gradient_steps_in_threads_are_the_same_bit_for_bit(monkeypatch):
    # the learner's threads run the chunks concurrently; weights and losses must not change by a bit (b = 2,097 is a
    # batch size at which torch rounds differently when the chunks change, so the threads must keep them)
    n, b = 6, 2097
    monkeypatch.setattr(col_marl, "CHUNK_ROWS", 2 * b)  # 2 agents per chunk: 3 chunks
    g = torch.Generator().manual_seed(0)
    batch = (torch.rand(n, b, 6, generator=g), torch.randint(0, 5, (n, b), generator=g), torch.rand(n, b, generator=g),
             torch.rand(n, b, 6, generator=g), torch.rand(n, b, 5, generator=g), torch.zeros(n, b), torch.tensor([True] * 5 + [False]), None)
    out = []
    for threads in (1, 2, 3):
        net = RouteAgentsQ(n, 6, torch.Generator().manual_seed(0))
        opt = torch.optim.Adam(net.parameters(), lr=1e-3)
        losses = [dqn_update(net, opt, batch, threads) for _ in range(3)]
        out.append((losses, [p.detach().clone() for p in net.parameters()]))
    for losses, params in out[1:]:
        np.testing.assert_array_equal(losses, out[0][0])
        assert all(torch.equal(p, q) for p, q in zip(params, out[0][1]))
    assert not torch.equal(out[0][1][0][0], RouteAgentsQ(n, 6, torch.Generator().manual_seed(0)).w1[0])  # it did learn


def test_replay_buffers_keep_the_target_networks_q_of_every_next_state():
    gen = torch.Generator().manual_seed(0)
    target = RouteAgentsQ(3, 6, gen)
    buffers = ReplayBuffers(3, 6, size=10, n_actions=5)
    rng = np.random.default_rng(0)
    for n in (7, 9):  # the second episode wraps agent 0's ring
        agent = np.array([0] * (n - 2) + [2, 2])
        buffers.add({"agent_idx": agent, "state": rng.random((n, 6), np.float32), "action": rng.integers(0, 5, n),
                     "reward": rng.random(n, np.float32), "next_state": rng.random((n, 6), np.float32), "done": np.zeros(n, np.float32)}, target)

    def check():
        with torch.no_grad():
            expected = target(torch.from_numpy(buffers.next_state)).numpy()
        for k, size in enumerate(buffers.size):
            np.testing.assert_allclose(buffers.target_q[k, :size], expected[k, :size], rtol=1e-5, atol=1e-6)

    assert buffers.size.tolist() == [10, 0, 4]
    check()
    with torch.no_grad():
        target.w1.add_(1.0)  # a target-network update
    buffers.refresh(target, chunk=3)
    check()


def test_long_runs_show_their_progress_at_least_every_few_minutes():
    due = [e for e in range(15_000) if col_marl._progress_due(e, 15_000, since_last_line_s=0.0)]
    assert due == [*range(0, 15_000, 1_500), 14_999]  # every 10 % and the last
    assert col_marl._progress_due(7, 15_000, since_last_line_s=col_marl.PROGRESS_EVERY_S)  # and at least this often
    assert not col_marl._progress_due(7, 15_000, since_last_line_s=col_marl.PROGRESS_EVERY_S - 1)
    assert col_marl._pace(100, 11_720, seconds=160.0) == " (37.5 episodes/min, ~5 h 13 min left)"
    assert col_marl._pace(1, 10, seconds=59.0) == ""  # no rate from under a minute
