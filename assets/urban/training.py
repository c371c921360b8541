"""Training of the route agents: col-MARL and the i-MARL ablation on every trained scenario."""

import time

import dagster as dg
import polars as pl
from pydantic import Field

from assets.figures import add_plot
from assets.profiles import check_names, default_profile, resolve
from warehouse.artifacts import artifact_path, write_bytes_atomic

# per profile: episodes per (scenario, method, seed), seeds, and the scenarios some methods are limited to (the others
# train on every trained scenario); the thesis trains 15,000 episodes (13,000 exploring). The demo trains chapter 3's
# method and i-MARL on Sc1 only: the thesis compares i-MARL with col-MARL on the artificial networks only (Table 4.3;
# the real-network tables 4.4-4.9 are col-MARL vs IDM), and ch3's CNN gradient steps cost several times col-MARL's.
PROFILE = {"demo": {"episodes": 50, "seeds": [0], "method_scenarios": {"ch3_dqn_cnn": ["sc1"], "i_marl": ["sc1"]}},
           "paper": {"episodes": 15000, "seeds": list(range(10)), "method_scenarios": {}}}


class TrainingConfig(dg.Config):
    profile: str = Field(default_factory=default_profile, description="demo: 50 episodes, seed 0; paper: 15,000 episodes, seeds 0-9")
    episodes: int | None = Field(default=None, description="training episodes per scenario, method and seed (None: the profile's)")
    seeds: list[int] | None = Field(default=None, description="training seeds, one policy set each (None: the profile's)")
    methods: list[str] = Field(default=["col_marl", "i_marl", "ch3_dqn_cnn"],
                                description="col_marl, i_marl and/or ch3_dqn_cnn (chapter 3: speed actions, DQN + CNN over the collision matrix)")
    method_scenarios: dict[str, list[str]] | None = Field(
        default=None, description="method -> the only scenarios it trains on; methods not named train on all (None: the profile's; "
        "demo: ch3_dqn_cnn and i_marl on sc1)")
    workers: int | None = Field(default=None, description="episodes run in parallel, one libsumo process each (None: usable cores)")
    gradient_steps: int | None = Field(
        default=None, description="gradient steps after each episode (None: 40 for col_marl / i_marl, 10 for ch3_dqn_cnn; the thesis does not say)")
    leader_guard: bool = Field(
        default=True,
        description="SUMO's car-following safety for col_marl / i_marl: each vehicle is capped at the safe speed behind its leader "
        "(no rear-end collisions), junction crossings stay the agents' job, as for the thesis's IDM baseline (docs/urban.md). "
        "False: every SUMO check off. The policies keep it for evaluation.",
    )
    checkpoint_minutes: float = Field(
        default=10.0, ge=0, description="save each run's training state this often (and when it ends) under checkpoints/, so that "
        "materialising again after an interruption resumes each unfinished run where it stopped and skips the finished ones, "
        "with the numbers of an uninterrupted run; removed once the asset succeeds. 0: no checkpoints")


def training_plan(config: TrainingConfig, trained_scenarios: list[str]) -> dict:
    """episodes, seeds and method_scenarios of the config or its profile; one line, before any episode, for a config
    that would fail after hours of training or train nothing (an unknown method or scenario, no method)."""
    from models.urban.experiments import METHODS_RL

    plan = resolve(config, PROFILE)
    only_on = plan["method_scenarios"]
    check_names("urban methods", config.methods, METHODS_RL)
    check_names("urban methods", [*config.methods, *only_on], METHODS_RL)  # method_scenarios' keys too
    strangers = sorted({s for names in only_on.values() for s in names} - set(trained_scenarios))
    if strangers:
        raise ValueError(f"method_scenarios names {strangers}, not trained scenarios: expected some of {', '.join(trained_scenarios)}")
    return plan


@dg.asset(group_name="urban", description="DDQN route agents trained per scenario, method and seed; training log and model files.")
def urban_training(context: dg.AssetExecutionContext, config: TrainingConfig, urban_scenarios: pl.DataFrame, urban_routes: pl.DataFrame) -> dg.Output:
    import torch

    from models.urban import col_marl
    from models.urban.experiments import METHODS_RL, files_of, route_agents, training_frame
    from models.urban.plots import training_curves_png
    from models.urban.policy_file import policy_bytes
    from models.parallel import ProcessPool, usable_cores

    torch.set_num_threads(1)
    train = urban_scenarios.filter(pl.col("role") == "train")
    plan = training_plan(config, train["scenario"].unique(maintain_order=True).to_list())
    episodes, seeds, only_on = plan["episodes"], plan["seeds"], plan["method_scenarios"]
    frames, timings, learner_cpu, checkpoints = [], {}, {}, []  # learner CPU: this process (gradient steps), whatever the machine's load
    with ProcessPool(config.workers or usable_cores(), col_marl.run_episode) as pool:
        for (scenario,), g in train.group_by("scenario", maintain_order=True):
            copies = [(files_of(r), r["n_vehicles"]) for r in g.iter_rows(named=True)]
            agents = route_agents(urban_routes, g)
            for method in config.methods:
                if scenario not in only_on.get(method, [scenario]):
                    continue
                for seed in seeds:
                    t, cpu = time.perf_counter(), time.process_time()
                    log = lambda msg: context.log.info(f"{scenario} seed {seed}: {msg}")  # noqa: E731
                    checkpoint = artifact_path("checkpoints", f"urban_{scenario}_{method}_seed{seed}.ckpt") if config.checkpoint_minutes else None
                    params, rows = col_marl.train(copies, agents, METHODS_RL[method], episodes, seed, pool, log, config.leader_guard,
                                                    config.gradient_steps, checkpoint_path=checkpoint, checkpoint_every_s=60 * config.checkpoint_minutes)
                    checkpoints += [checkpoint] if checkpoint else []
                    path = write_bytes_atomic(artifact_path("models", f"urban_{scenario}_{method}_seed{seed}.pt"), policy_bytes(
                        params, agents, config.leader_guard, variant=METHODS_RL[method], scenario=scenario, seed=seed,
                        episodes=episodes, gradient_steps=config.gradient_steps))
                    timings[f"{scenario}/{method}/seed{seed}"] = round(time.perf_counter() - t, 1)
                    learner_cpu[f"{scenario}/{method}/seed{seed}"] = round(time.process_time() - cpu, 1)
                    frames.append(training_frame(rows, scenario, method, seed, str(path)))
    df = pl.concat(frames).select("scenario", "method", "seed", "agent", "episode", "return", "epsilon", "loss", "model_path")
    last = df.filter(pl.col("episode") >= episodes - max(episodes // 10, 1)).group_by("scenario", "method").agg(
        pl.col("return").mean().alias("mean_return_last_10pct"))
    context.log.info(f"trained {len(timings)} policy sets in {sum(timings.values()):.0f} s: {timings}")
    for path in checkpoints:
        path.unlink(missing_ok=True)
    metadata = {"train_seconds": dg.MetadataValue.json(timings), "learner_cpu_seconds": dg.MetadataValue.json(learner_cpu), "episodes": episodes,
                "leader_guard": config.leader_guard, "final_returns": dg.MetadataValue.json(last.to_dicts()), "workers": config.workers or usable_cores()}
    add_plot(metadata, "urban_training_curves", training_curves_png(df))
    return dg.Output(df, metadata=metadata)
