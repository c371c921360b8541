"""Bench: batched trajectory roll-outs with the policy in the loop vs one trajectory at a time (same env + policy).

Targets (issue 3): batched >= 50x the one-at-a-time loop and >= 250,000 state-steps/s on 2 cores; also
reports one GAIL iteration's time. Run with `make bench` (or pytest tests/bench/test_bench_trajectory.py -s).
"""

import time

import numpy as np
import polars as pl
import torch

from models.aviation.weather import read_weather
from models.trajectory.env import EnvConfig, TrajectoryEnv, WeatherCube, rollout
from models.trajectory.nets import Policy, Scaler
from models.trajectory.env import OBS_DIM

BATCH = 8192
STEPS = 60
SINGLE_TRAJECTORIES = 20
TARGET_RATIO = 50.0
TARGET_STEPS_PER_S = 250_000
# As the trajectory assets do: with 2 intra-op threads, any other load on a 2-core machine makes OpenMP's
# threads wait on each other (measured here: 40-50k state-steps/s with 2 threads vs 300-365k with 1, load ~3).
THREADS = 1


def _env_and_policy():
    from benchlib import REPO

    weather = read_weather(REPO / "data" / "weather" / "gfs_2011_isobaric_t_u_v.grib2")
    bbox = (17.7, 54.8, 37.7, 60.1)
    cube = WeatherCube(weather, (bbox[0] - 1, bbox[1] - 1, bbox[2] + 1, bbox[3] + 1), int(np.datetime64("2022-02-27T06:00", "us").astype(np.int64)))
    env = TrajectoryEnv(cube, bbox, EnvConfig())
    policy = Policy(4, Scaler(torch.zeros(OBS_DIM), torch.ones(OBS_DIM)), Scaler(torch.tensor([1.6, 0.0, 0.0]), torch.tensor([0.2, 0.1, 10.0]))).eval()
    return env, policy


def _run(env, policy, n: int) -> int:
    """Roll out n trajectories from Moscow towards Kaliningrad for STEPS steps; returns state-steps done."""
    start = torch.tensor([[37.5, 56.0, 9000.0]], dtype=torch.float64).repeat(n, 1)
    goal = torch.tensor([[20.6, 54.9, 9000.0]], dtype=torch.float64).repeat(n, 1)
    mode = torch.arange(n) % 4
    with torch.no_grad():
        ro = rollout(env, lambda o: policy.act(o, mode)[0], start, goal, STEPS, torch.zeros(n, dtype=torch.float64), torch.full((n,), 787.0))
    return int(ro.live.sum())


def test_batched_rollouts_vs_one_at_a_time(bench_results):
    torch.set_num_threads(THREADS)
    env, policy = _env_and_policy()
    _run(env, policy, 64)  # warm-up
    t0 = time.perf_counter()
    single_steps = sum(_run(env, policy, 1) for _ in range(SINGLE_TRAJECTORIES))
    single_rate = single_steps / (time.perf_counter() - t0)
    t0 = time.perf_counter()
    batched_steps = _run(env, policy, BATCH)
    batched_rate = batched_steps / (time.perf_counter() - t0)
    ratio = batched_rate / single_rate
    bench_results["trajectory_rollouts"] = {"single_state_steps_per_s": round(single_rate), "batched_state_steps_per_s": round(batched_rate),
                                            "ratio": round(ratio, 1), "batch": BATCH, "steps": STEPS, "target_ratio": TARGET_RATIO,
                                            "target_state_steps_per_s": TARGET_STEPS_PER_S}
    print(f"\nBENCH trajectory roll-outs: one-at-a-time {single_rate:,.0f} state-steps/s; batched ({BATCH}): {batched_rate:,.0f} state-steps/s; ratio {ratio:.0f}x")
    assert ratio >= TARGET_RATIO
    assert batched_rate >= TARGET_STEPS_PER_S


def test_gail_iteration_time(bench_results):
    """One Triple-GAIL-GP iteration (256 roll-outs x 45 steps, D/selector updates, PPO) on synthetic expert pairs."""
    from models.trajectory import triple_gail
    from models.trajectory.nets import Selector
    from models.trajectory.task import Task

    torch.set_num_threads(THREADS)
    env, _ = _env_and_policy()
    n = 20_000
    g = torch.Generator().manual_seed(0)
    starts = torch.stack([37.5 - 16 * torch.rand(n, generator=g, dtype=torch.float64), 55 + 2 * torch.rand(n, generator=g, dtype=torch.float64),
                          torch.full((n,), 10_000.0, dtype=torch.float64)], 1)
    goal = torch.tensor([[20.6, 54.9, 9000.0]], dtype=torch.float64).repeat(n, 1)
    modes = torch.arange(n) % 4
    obs = env.observe(starts, torch.zeros(n, dtype=torch.float64), goal, torch.full((n,), 787.0, dtype=torch.float64))
    actions = torch.stack([1.6 + 0.1 * torch.randn(n, generator=g), 0.1 * torch.randn(n, generator=g), torch.zeros(n)], 1).double()
    task = Task("cruise", env, 4, [("A-B", k) for k in range(4)], goal[:4], 300, obs, actions, modes, starts, torch.zeros(n, dtype=torch.long),
                torch.full((n,), 787.0, dtype=torch.float64), goal, Scaler(obs.mean(0), obs.std(0)), Scaler(actions.mean(0), actions.std(0)))
    policy = Policy(4, task.obs_scaler, task.act_scaler)
    t0 = time.perf_counter()
    triple_gail.train(policy, Selector(4, task.obs_scaler), task, 1, "bce_gp", g)
    elapsed = time.perf_counter() - t0
    bench_results["triple_gail_iteration"] = {"seconds": round(elapsed, 2), "trajectories": triple_gail.N_TRAJECTORIES, "horizon": triple_gail.HORIZON}
    print(f"\nBENCH one Triple-GAIL-GP iteration ({triple_gail.N_TRAJECTORIES} roll-outs x {triple_gail.HORIZON} steps): {elapsed:.2f} s")
    assert elapsed < 60
