"""AppLearn (inverse RL, Alg 7) and the SVM behavioural-cloning baseline under the Table 6.1 protocol.

tracks_20s, trajectory_modes, weather -> applearn_models (catalogue + model files), applearn_results
"""

import time

import dagster as dg
import polars as pl
from pydantic import Field

from assets.profiles import default_profile, resolve

# Profile defaults for the protocol; the learner's own budgets are models.trajectory.applearn.PROFILES.
PROTOCOL = {
    # demo: the two largest clusters (both UUEE-UMKK modes), like the thesis's two BCN-MAD clusters
    "demo": {"seeds": [0, 1, 2, 3, 4], "partitions": ["P1", "P2", "P3", "P4"], "min_flights": 25},
    "paper": {"seeds": list(range(10)), "partitions": ["P1", "P2", "P3", "P4"], "min_flights": 20},
}


class AppLearnConfig(dg.Config):
    profile: str = Field(default_factory=default_profile, description="demo (minutes on 2 cores) or paper (thesis budgets)")
    seeds: list[int] | None = Field(default=None, description="seeds of the partition draws and training [demo 0-4, paper 0-9]")
    partitions: list[str] | None = Field(default=None, description="Table 6.1 partitions [P1-P4]")
    min_flights: int | None = Field(default=None, description="datasets = whole-flight clusters with at least this many flights [demo 25, paper 20]")
    episodes: int | None = Field(default=None, description="DQN training episodes [demo 768, paper 15000]")
    reward_scales: list[float] | None = Field(
        default=None, description="DQN reward scales, one training each, the best on validation flights kept [demo 0.01, paper 1, 0.1, 0.01]")
    workers: int | None = Field(default=None, description="runs in parallel, one process (one core) each [None: the usable cores]")


@dg.multi_asset(
    group_name="trajectory",
    outs={
        "applearn_models": dg.AssetOut(description="Trained AppLearn models per dataset, partition and seed; one model file each."),
        "applearn_results": dg.AssetOut(description="Success rate and DTW-matched RMSE of AppLearn and SVM BC on held-out flights (Table 6.1)."),
    },
)
def applearn_experiments(context: dg.AssetExecutionContext, config: AppLearnConfig, tracks_20s: pl.DataFrame,
                         trajectory_modes: pl.DataFrame, weather: pl.DataFrame):
    import torch

    from models.trajectory.applearn import demo_or_paper
    from models.parallel import ProcessPool, usable_cores
    from models.trajectory.applearn_eval import datasets, run_partition_job, table_6_1
    from models.markdown import markdown_table
    from warehouse.artifacts import artifact_path, write_bytes_atomic

    protocol = resolve(config, PROTOCOL)
    torch.set_num_threads(1)  # small nets: more threads only add overhead
    params = demo_or_paper(config.profile, episodes=config.episodes,
                           reward_scales=None if config.reward_scales is None else tuple(config.reward_scales))
    sets = datasets(tracks_20s, trajectory_modes, protocol["min_flights"])
    todo = [(d, p, s) for d in sets for p in protocol["partitions"] for s in protocol["seeds"]]
    context.log.info(f"{len(todo)} runs: datasets {list(sets)}, {protocol}, {params.episodes} episodes each")
    models, results, t0 = [], [], time.perf_counter()
    jobs = [(sets[name], weather, partition, seed, params) for name, partition, seed in todo]
    # each run trains on one thread: the runs share the cores as parallel processes
    with ProcessPool(config.workers or usable_cores(), run_partition_job) as pool:
        for k, ((name, partition, seed), (model_bytes, row, res)) in enumerate(zip(todo, pool.iter(jobs)), 1):
            path = write_bytes_atomic(artifact_path("models/applearn", f"{name.replace('/', '_mode')}_{partition}_seed{seed}.pt"), model_bytes)
            models.append({"dataset": name, **row, "profile": config.profile, "path": str(path)})
            results += [{"dataset": name, **r} for r in res]
            a, b = res
            context.log.info(f"[{k}/{len(todo)}] {name} {partition} seed {seed}: {row['train_s']:.0f} s; success AppLearn "
                             f"{a['success_rate']:.2f} / SVM {b['success_rate']:.2f}, RMSE {a['rmse_3d_km']:.1f} / {b['rmse_3d_km']:.1f} km")
    results = pl.DataFrame(results)
    meta = {"runs": len(todo), "seconds": round(time.perf_counter() - t0, 1), "profile": config.profile,
            "table_6_1": dg.MetadataValue.md(markdown_table(table_6_1(results)))}
    return dg.Output(pl.DataFrame(models), output_name="applearn_models", metadata={"runs": len(todo)}), \
        dg.Output(results, output_name="applearn_results", metadata=meta)
