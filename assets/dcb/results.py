"""Metrics per case, method and seed, the thesis-style summary (Tables 5.2-5.3) and the figures."""

import dagster as dg
import numpy as np
import polars as pl

from assets.comparisons import comparisons_output
from assets.dcb.cases import problems
from assets.figures import add_plot
from models.dcb.experiment import comparisons, results, summary, summary_markdown
from models.dcb.plots import box_plots, delay_histogram, demand_vs_capacity
from models.dcb.train import METHODS


@dg.asset(group_name="dcb", description="Average delay (>= 4 min), regulated flights, hotspots left, total delay and gap to the optimum per run.")
def dcb_results(context: dg.AssetExecutionContext, dcb_delays: pl.DataFrame, dcb_reference: pl.DataFrame, dcb_cases: pl.DataFrame,
                dcb_sector_entries: pl.DataFrame, dcb_sectors: pl.DataFrame, dcb_flights: pl.DataFrame) -> dg.Output:
    probs = problems(dcb_cases, dcb_sector_entries, dcb_sectors, dcb_flights)
    optimum = dict(dcb_reference.filter(pl.col("method") == "optimum").group_by("case").agg(pl.col("delay_min").sum()).iter_rows())
    delays = pl.concat([dcb_reference, dcb_delays.drop("episodes")], how="diagonal")
    df = results(delays, probs, optimum)
    metadata = {"runs": df.height, "runs_with_hotspots_left": int((df["hotspots_left"] > 0).sum())}
    for case, problem in probs.items():
        zero = np.zeros(problem.n_flights, dtype=np.int64)
        for method in ("HCMARL", "optimum"):
            one = delays.filter((pl.col("case") == case) & (pl.col("method") == method))
            if one.is_empty():
                continue
            seed = one["seed"].min()
            d = pl.DataFrame({"flight_id": problem.flight_ids}).join(one.filter(pl.col("seed") == seed), on="flight_id", how="left")
            add_plot(metadata, f"dcb_demand_capacity_{case}_{method}",
                  demand_vs_capacity(problem, zero, d["delay_min"].fill_null(0).to_numpy(), f"{case}: {method} (seed {seed})"))
        add_plot(metadata, f"dcb_delay_histogram_{case}", delay_histogram(delays.filter(pl.col("case") == case), f"{case}: delays per method"))
    context.log.info(f"{df.height} runs, {metadata['runs_with_hotspots_left']} leave hotspots")
    return dg.Output(df, metadata=metadata)


@dg.asset(group_name="dcb", description="Mean, std, median and IQR over seeds per case, method and metric (Tables 5.2-5.3), and Fig 5.7.")
def dcb_summary(dcb_results: pl.DataFrame) -> dg.Output:
    summ = summary(dcb_results)
    metadata = {"tables": dg.MetadataValue.md(summary_markdown(summ))}
    learners = [m for m in METHODS if m in set(dcb_results["method"])]
    if learners:
        add_plot(metadata, "dcb_box_plots", box_plots(dcb_results, learners))
    return dg.Output(summ, metadata=metadata)


@dg.asset(group_name="dcb", description="HCMARL against CMARL and MIRL per case, paired over training seeds (sign-flip test).")
def dcb_comparisons(context: dg.AssetExecutionContext, dcb_results: pl.DataFrame) -> dg.Output:
    return comparisons_output(context, comparisons(dcb_results))
