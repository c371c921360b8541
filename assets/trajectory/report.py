"""Report: the thesis's Tables 6.1 and 7.2-7.9 and Figs 7.11-7.13 for our data, a rerun recording and an MCAP export.

trajectory_metrics, trajectory_error_growth, mode_posteriors, trajectory_predictions, applearn_results -> trajectory_report
"""

import dagster as dg
import polars as pl

from warehouse.artifacts import artifact_path, save_plot, write_bytes_atomic


@dg.asset(group_name="trajectory", description="Thesis Tables 6.1, 7.2-7.9 and error-growth Figs 7.11-7.13 as metadata; rerun + MCAP of actual vs predicted.")
def trajectory_report(context: dg.AssetExecutionContext, trajectory_metrics: pl.DataFrame, trajectory_error_growth: pl.DataFrame,
                      mode_posteriors: pl.DataFrame, trajectory_predictions: pl.DataFrame, tracks_20s: pl.DataFrame,
                      applearn_results: pl.DataFrame):
    from models.trajectory.applearn_eval import table_6_1
    from models.trajectory.recording import points_for_recording, write_location_fix_mcap, write_prediction_recording
    from models.markdown import markdown_table
    from models.trajectory.report import growth_figure, growth_rates, thesis_tables

    files, meta = [], {}
    tables = {"table_6_1": markdown_table(table_6_1(applearn_results)), **thesis_tables(trajectory_metrics, mode_posteriors)}
    for item, md in tables.items():
        path = write_bytes_atomic(artifact_path("reports/trajectory", f"{item}.md"), md.encode())
        files.append((item, "markdown", path))
        meta[item] = dg.MetadataValue.md(md)
    rates = growth_rates(trajectory_error_growth)
    meta["error_growth_rates"] = dg.MetadataValue.md(markdown_table(rates))
    for number, phase in (("7_11", "climb"), ("7_12", "cruise"), ("7_13", "descent")):
        path, md = save_plot(f"trajectory_figure_{number}_{phase}", growth_figure(trajectory_error_growth, phase))
        files.append((f"figure_{number}_{phase}", "png", path))
        meta[f"figure_{number}_{phase}"] = dg.MetadataValue.md(md)
    points = points_for_recording(tracks_20s, trajectory_predictions, seed=0)
    rrd = write_prediction_recording(points, artifact_path("recordings", "trajectory_predictions.rrd"))
    mcap = write_location_fix_mcap(points, artifact_path("recordings", "trajectory_predictions.mcap"))
    files += [("rerun", "rrd", rrd), ("mcap", "mcap", mcap)]
    context.log.info(f"rerun {rrd}  |  MCAP (foxglove.LocationFix) {mcap}")
    meta["rerun_recording"] = dg.MetadataValue.path(str(rrd))
    meta["mcap"] = dg.MetadataValue.path(str(mcap))
    table = pl.DataFrame({"item": [f[0] for f in files], "kind": [f[1] for f in files], "path": [str(f[2]) for f in files],
                          "size_bytes": [f[2].stat().st_size for f in files]})
    return dg.Output(table, metadata=meta)
