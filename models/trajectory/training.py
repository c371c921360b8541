"""Train one model bundle: BC (single scheme), or Triple-/sInfo-GAIL-GP under MMIL (a model per phase) or SMIL
(one model over whole flights). Every model is seeded: the same seed gives the same weights.
"""

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl
import torch

from models.trajectory import sinfo_gail, triple_gail
from models.trajectory.bc import train_bc, train_mode_classifier
from models.trajectory.data import PHASES, Demonstrations, TrajectoryDataError, demonstrations, per_route
from models.trajectory.env import EnvConfig, TrajectoryEnv, WeatherCube
from models.trajectory.model import TrajectoryModel
from models.trajectory.nets import Policy, Selector
from models.trajectory.task import Task, build_task

GAILS = {"triple_gail": triple_gail, "sinfo_gail": sinfo_gail}
SCHEME_PHASES = {"MMIL": PHASES, "SMIL": ("all",), "single": ("all",)}


@dataclass
class Budget:
    bc_epochs: int
    gail_iterations: int


@dataclass
class Setup:
    """Demonstrations (train, test) per phase and the environment they live in."""

    demos: dict[str, tuple[Demonstrations, Demonstrations]]
    env: TrajectoryEnv
    dt_s: float
    tasks: dict[tuple[str, bool], Task]  # (phase, per_route) -> task, built on first use

    def task(self, phase: str, by_route: bool = False) -> Task:
        if (phase, by_route) not in self.tasks:
            train = self.demos[phase][0]
            self.tasks[(phase, by_route)] = build_task(per_route(train) if by_route else train, self.env, self.dt_s)
        return self.tasks[(phase, by_route)]


def prepare(tracks: pl.DataFrame, modes: pl.DataFrame, flights: pl.DataFrame, splits: pl.DataFrame,
            weather: pl.DataFrame, dt_s: float) -> Setup:
    # the actions are per step: 10 s tracks read as 20 s ones halve every speed and double every time
    step_us = tracks.select(pl.col("ts").diff().over("flight_id").dt.total_microseconds().mode().first()).item()
    if step_us is not None and step_us != round(dt_s * 1e6):  # in whole µs, as resample makes the grid
        raise TrajectoryDataError(f"tracks_20s has a {step_us / 1e6:g} s step but dt_s is {dt_s:g} s: "
                                  "set dt_s of trajectory_models and trajectory_evaluation to the tracks' step")
    demos = {p: demonstrations(tracks, modes, flights, splits, p) for p in (*PHASES, "all")}
    bbox = (float(tracks["lon"].min()), float(tracks["lat"].min()), float(tracks["lon"].max()), float(tracks["lat"].max()))
    when_us = int(tracks["ts"].dt.epoch("us").median())
    cube = WeatherCube(weather, (bbox[0] - 1, bbox[1] - 1, bbox[2] + 1, bbox[3] + 1), when_us)
    return Setup(demos, TrajectoryEnv(cube, bbox, EnvConfig(dt_s=dt_s)), dt_s, {})


def method_name(algorithm: str, discriminator: str | None) -> str:
    return algorithm if discriminator is None else f"{algorithm}_{discriminator}"


def train_model(setup: Setup, algorithm: str, scheme: str, seed: int, budget: Budget,
                discriminator: str | None = None) -> tuple[TrajectoryModel, dict]:
    """algorithm ∈ {bc, triple_gail, sinfo_gail}; scheme ∈ {MMIL, SMIL} for GAILs, "single" for BC."""
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    name = method_name(algorithm, discriminator)
    tasks, policies, selectors, history = [], [], [], {}
    t0 = time.perf_counter()
    for phase in SCHEME_PHASES[scheme]:
        task = setup.task(phase, by_route=algorithm == "bc")
        policy = Policy(task.n_modes, task.obs_scaler, task.act_scaler)
        h = {"bc_loss": train_bc(policy, task, budget.bc_epochs, gen)}
        selector = None
        if algorithm in GAILS:
            selector = Selector(task.n_modes, task.obs_scaler)
            h["selector_warm_loss"] = train_mode_classifier(selector, policy, task, budget.bc_epochs, gen)
            h.update(GAILS[algorithm].train(policy, selector, task, budget.gail_iterations, discriminator, gen))
        policy.eval()
        tasks.append(task), policies.append(policy), selectors.append(selector)
        history[phase] = h
    config = {"name": f"{name}_{scheme}_seed{seed}", "method": name, "algorithm": algorithm, "discriminator": discriminator,
              "scheme": scheme, "seed": seed, "dt_s": setup.dt_s, "bc_epochs": budget.bc_epochs,
              "gail_iterations": budget.gail_iterations, "train_seconds": round(time.perf_counter() - t0, 2)}
    return TrajectoryModel.from_tasks(config, tasks, policies, selectors), history


def random_policy_like(model: TrajectoryModel, seed: int) -> TrajectoryModel:
    """The same bundle with untrained policies (for the 'learned beats random' test and as a sanity baseline)."""
    torch.manual_seed(seed)
    phases = []
    for pm in model.phases:
        fresh = Policy(len(pm.mode_keys), pm.policy.obs_scaler, pm.policy.act_scaler).eval()
        phases.append(type(pm)(pm.phase, fresh, None, pm.mode_keys, pm.goals, pm.max_steps))
    return TrajectoryModel({**model.config, "name": "random"}, phases, model.cube, model.bbox)


# Profile defaults (Dagster config fields left unset take these). The thesis reports means of 10 runs; it
# gives no epoch counts, so "paper" uses budgets large enough for the losses to flatten on this data.
PROFILE_DEFAULTS = {
    "demo": {"seeds": [0, 1, 2, 3, 4], "bc_epochs": 20, "gail_iterations": 3, "discriminators": ["bce_gp"],
             "algorithms": ["triple_gail", "sinfo_gail"]},
    "paper": {"seeds": list(range(10)), "bc_epochs": 200, "gail_iterations": 300, "discriminators": ["wgan_gp", "bce_gp"],
              "algorithms": ["triple_gail", "sinfo_gail"]},
}


def runs(algorithms: list[str], discriminators: list[str], seeds: list[int]) -> list[tuple[str, str, int, str | None]]:
    """(algorithm, scheme, seed, discriminator) of every bundle to train: each GAIL under MMIL and SMIL, plus BC."""
    out = [(a, s, seed, d) for seed in seeds for a in algorithms for d in discriminators for s in ("MMIL", "SMIL")]
    return out + [("bc", "single", seed, None) for seed in seeds]


def train_and_save(job: tuple) -> dict:
    """One model bundle, for a worker process: (setup, algorithm, scheme, seed, budget, discriminator, folder,
    profile) -> its catalogue row, the model file written to folder/<name>.pt. train_model seeds itself,
    so the result does not depend on where it ran."""
    setup, algorithm, scheme, seed, budget, discriminator, folder, profile = job
    model, history = train_model(setup, algorithm, scheme, seed, budget, discriminator)
    Path(folder).mkdir(parents=True, exist_ok=True)
    path = model.save(Path(folder) / f"{model.config['name']}.pt")
    return catalogue_row(model, history, setup, profile, str(path))


def catalogue_row(model: TrajectoryModel, history: dict, setup: Setup, profile: str, path: str) -> dict:
    c = model.config
    return {"name": c["name"], "method": c["method"], "algorithm": c["algorithm"], "discriminator": c["discriminator"],
            "scheme": c["scheme"], "seed": c["seed"], "profile": profile, "bc_epochs": c["bc_epochs"],
            "gail_iterations": c["gail_iterations"], "phases": ",".join(pm.phase for pm in model.phases),
            "expert_pairs": sum(len(setup.task(pm.phase, c["algorithm"] == "bc").obs) for pm in model.phases),
            "final_bc_loss": float(np.mean([h["bc_loss"][-1] for h in history.values()])),
            "train_s": c["train_seconds"], "path": path}
