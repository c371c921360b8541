"""Evaluation on held-out copies against SUMO's IDM and Krauss; paired comparisons over seeds; trajectories, Fig 4.4,
rerun replay, thesis tables."""

import time

import dagster as dg
import polars as pl
from pydantic import Field

from assets.comparisons import comparisons_output
from models.parallel import ProcessPool, usable_cores
from models.markdown import markdown_table
from models.urban.experiments import EVALUATION_METHODS, comparisons, evaluation_jobs, results_rows, run_job, thesis_markdown, thesis_tables, trajectories_rows
from warehouse.artifacts import artifact_path, save_plot


class EvaluationConfig(dg.Config):
    methods: list[str] = Field(default=EVALUATION_METHODS, description="methods to evaluate (RL methods need their urban_training policies)")
    workers: int | None = Field(default=None, description="episodes run in parallel, one libsumo process each (None: usable cores)")
    scenarios: list[str] | None = Field(default=None, description="evaluate only these scenarios' held-out copies (None: every scenario)")
    copies: int | None = Field(default=None, description="at most this many held-out copies per scenario, the lowest-numbered (None: all)")


def _run(context, jobs, workers):
    """Run the (row keys, job) pairs of evaluation_jobs in worker processes: (row keys, outputs) in the same order."""
    t = time.perf_counter()
    with ProcessPool(workers, run_job) as pool:
        outputs = pool([j for _, j in jobs])
    context.log.info(f"{len(jobs)} episodes in {time.perf_counter() - t:.1f} s")
    return [k for k, _ in jobs], outputs


@dg.asset(group_name="urban", description="Metrics of every method on every copy not used in training (greedy policies, ε = 0).")
def urban_results(context: dg.AssetExecutionContext, config: EvaluationConfig, urban_scenarios: pl.DataFrame, urban_training: pl.DataFrame) -> dg.Output:
    from models.urban.policy_file import load_policies  # imports torch: not at definitions load

    jobs = evaluation_jobs(urban_scenarios, load_policies(urban_training), config.methods, scenarios=config.scenarios, copies=config.copies)
    df = results_rows(*_run(context, jobs, config.workers or usable_cores()))
    summary = df.group_by("scenario", "method", maintain_order=True).agg(
        pl.len().alias("runs"), pl.col("avg_travel_time_s").mean(), pl.col("avg_speed_mps").mean(),
        pl.col("collisions").sum(), pl.col("teleports").sum(), pl.col("success").mean())
    return dg.Output(df, metadata={"summary": dg.MetadataValue.md(markdown_table(summary, cell=lambda v: f"{v:.2f}" if isinstance(v, float) else str(v)))})


@dg.asset(group_name="urban", description="Thesis tables 3.2, 4.3, 4.4, 4.5, 4.7-4.9 for our runs (mean ± std over copies x seeds).")
def urban_thesis_tables(urban_results: pl.DataFrame, urban_scenarios: pl.DataFrame) -> dg.Output:
    df = thesis_tables(urban_results, urban_scenarios)
    return dg.Output(df, metadata={"tables": dg.MetadataValue.md(thesis_markdown(df))})


@dg.asset(group_name="urban", description="i-MARL and the safety layer against col-MARL, paired over training seeds (sign-flip test).")
def urban_comparisons(context: dg.AssetExecutionContext, urban_results: pl.DataFrame) -> dg.Output:
    return comparisons_output(context, comparisons(urban_results))


@dg.asset(group_name="urban", description="1 s trajectories of one evaluation copy per trained scenario and method; Fig 4.4 profiles; rerun replay.")
def urban_trajectories(context: dg.AssetExecutionContext, config: EvaluationConfig, urban_scenarios: pl.DataFrame,
                       urban_training: pl.DataFrame, urban_routes: pl.DataFrame) -> dg.Output:
    from models.urban.plots import busiest_route, junction_offsets_m, route_profile_png
    from models.urban.policy_file import load_policies
    from models.urban.recording import write_episode_recording

    jobs = evaluation_jobs(urban_scenarios, load_policies(urban_training), config.methods, record=True,
                           scenarios=config.scenarios, copies=config.copies)
    df = trajectories_rows(*_run(context, jobs, config.workers or usable_cores()))
    metadata = {}
    for (scenario,), g in df.group_by("scenario", maintain_order=True):
        network = urban_scenarios.filter(pl.col("scenario") == scenario)["network"][0]
        route = busiest_route(g)
        r = urban_routes.filter((pl.col("network") == network) & (pl.col("route_id") == route)).row(0, named=True)
        png = route_profile_png(g, route, junction_offsets_m(r["edges"], r["net_path"]), f"{scenario}: route {route} (Fig 4.4)")
        _, md = save_plot(f"urban_profile_{scenario}", png)
        metadata[f"profile_{scenario}"] = dg.MetadataValue.md(md)
        rrd = write_episode_recording(g.filter(pl.col("method") == "col_marl"), r["net_path"],
                                      artifact_path("recordings", f"urban_{scenario}_col_marl.rrd"), f"{scenario}: col-MARL, evaluation copy")
        metadata[f"rerun_{scenario}"] = dg.MetadataValue.path(str(rrd))
        context.log.info(f"rerun recording: rerun {rrd}")
    return dg.Output(df, metadata=metadata)

