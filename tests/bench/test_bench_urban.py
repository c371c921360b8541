"""Urban env throughput: vehicle-steps per second of the RL environment (observations of Eq 4.2 for every
vehicle, Q-network actions, rewards) against plain SUMO running IDM on the same scenario, in the same run.

Two scenarios, one seeded copy each, 0.2 s steps for both: Sc1 at the thesis's size (150 vehicles over
600 s, Table 4.2: only a handful of vehicles on the road at a time, so the env's fixed Python cost per
1 s decision dominates) and the bundled real network with the large-scale demand LS_const (cars/buses/
trucks every 4/10/15 s, 10 min, 150 routes: ~100 vehicles on the road). A vehicle-step is one vehicle
simulated for one 0.2 s step. Plain SUMO: libsumo `simulationStep` in a loop with SUMO's IDM driving, no
subscriptions, no Python per vehicle. Both timed from SUMO's start to its close. Target (issue 4): env >= 0.5x, asserted on the dense scenario.
Best of 3 runs each (the machine is shared: see the load average printed).
"""

import time

import torch

import benchlib as b
from models.libsumo_import import import_libsumo
from models.urban.col_marl import EpisodeJob, RouteAgentsQ, numpy_params, run_episode
from models.urban.experiments import REAL_NET
from models.urban.network import artificial_network, enumerate_routes, sumo_network
from models.urban.scenarios import Demand, write_copy
from models.urban.sim import STEP_S, ScenarioFiles

libsumo = import_libsumo()
TARGET_RATIO = 0.5


SCENARIOS = {
    "sc1": (lambda out: artificial_network(1, out), 12, Demand(150, 600.0), 40.0),
    "real_ls_const": (lambda out: sumo_network(REAL_NET, out, 30.0), 150, Demand(0, 600.0, "ls"), 30.0),
}


def _scenario(tmp_path, name: str) -> tuple[ScenarioFiles, list[str]]:
    build, n_routes, demand, vmax = SCENARIOS[name]
    net = build(tmp_path / f"{name}.net.xml")
    routes = enumerate_routes(net, n_routes, 0)
    info = write_copy(tmp_path / name, net, routes, demand, vmax, seed=5)
    files = ScenarioFiles(str(net), info["routes_path"], info["folder"], info["last_depart_s"], vmax)
    return files, [f"{r['route_id']}:{c}" for r in routes for c in ("car", "heavy")]


def _plain_idm(files: ScenarioFiles) -> tuple[float, int]:
    """Timed from SUMO's start to its close, as the env's episode is (which starts and closes its own SUMO)."""
    t = time.perf_counter()
    libsumo.start(["sumo", "-n", files.net, "-a", files.vtypes("IDM"), "-r", files.routes, "--step-length", str(STEP_S),
                   "--no-step-log", "true", "--no-warnings", "true", "--collision.check-junctions", "true"])
    steps = 0
    while libsumo.simulation.getMinExpectedNumber() > 0:
        libsumo.simulationStep()
        steps += libsumo.vehicle.getIDCount()
    libsumo.close()
    return time.perf_counter() - t, steps


def _env(files: ScenarioFiles, agents: list[str]) -> tuple[float, int]:
    params = numpy_params(RouteAgentsQ(len(agents), 6, torch.Generator().manual_seed(0)))
    t = time.perf_counter()
    # ε = 0.1 keeps the traffic moving under an untrained network; the cost per step is the same either way
    res = run_episode(EpisodeJob(files, "col", agents, params, 0.1, 3, 150))
    return time.perf_counter() - t, res.vehicle_substeps


def _measure(tmp_path, name: str, bench_results) -> float:
    files, agents = _scenario(tmp_path, name)
    load = b.warn_if_busy(f"urban env {name}")
    runs = [(_plain_idm(files), _env(files, agents)) for _ in range(3)]  # interleaved: both see the same load
    plain, env = [p for p, _ in runs], [e for _, e in runs]
    plain_rate = max(s / w for w, s in plain)
    env_rate = max(s / w for w, s in env)
    ratio = env_rate / plain_rate
    bench_results[f"urban_env_{name}"] = {
        "scenario": name, "step_s": STEP_S, "plain_idm_vehicle_steps_per_s": round(plain_rate),
        "env_vehicle_steps_per_s": round(env_rate), "ratio": round(ratio, 3), "loadavg_before": round(load, 2),
        "plain_runs_s": [round(w, 2) for w, _ in plain], "env_runs_s": [round(w, 2) for w, _ in env],
    }
    print(f"\nBENCH urban env {name}: {env_rate:,.0f} vehicle-steps/s with observations + actions vs plain SUMO IDM "
          f"{plain_rate:,.0f}/s -> {ratio:.2f}x (target >= {TARGET_RATIO}x; best of 3, load {load:.1f})")
    return ratio


def test_env_vehicle_steps_per_second_vs_plain_idm(tmp_path, bench_results):
    _measure(tmp_path, "sc1", bench_results)  # reported, sparse traffic
    assert _measure(tmp_path, "real_ls_const", bench_results) >= TARGET_RATIO
