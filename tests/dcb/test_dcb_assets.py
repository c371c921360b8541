"""The DCB Dagster assets materialise on a small slice of the Swiss day (real data, few episodes)."""

from pathlib import Path

import dagster as dg
import polars as pl

from assets.dcb import ASSETS, CHECKS
from tests.conftest import SWISS
from warehouse.io_manager import ParquetIOManager
from warehouse.storage import read_table


def test_dcb_assets_materialise_on_a_slice(tmp_path):
    raw = pl.read_parquet(SWISS)
    start = raw.group_by("icao24").agg(pl.col("timestamp").min())
    aircraft = start.filter(pl.col("timestamp").dt.hour().is_between(8, 9))["icao24"].implode()
    sliced = raw.filter(pl.col("icao24").is_in(aircraft))
    path = tmp_path / "swiss_slice.parquet"
    sliced.write_parquet(path)
    result = dg.materialize(ASSETS + CHECKS, resources={"io_manager": ParquetIOManager()}, run_config={"ops": {
        "dcb_airspace": {"config": {"source_path": str(path)}},
        "dcb_cases": {"config": {"capacity_scales": [0.9]}},
        "dcb_delays": {"config": {"episodes": 5, "seeds": [0, 1], "methods": ["MIRL", "HCMARL"], "workers": 2}},
    }})
    assert result.success
    summary = read_table("dcb_demand_summary")
    rows = dict(zip(summary["outcome"] + summary["reason"], summary["rows"]))
    assert rows["read"] == sliced.height == rows["kept"] + read_table("dcb_demand_rejects").height
    flights, entries = read_table("dcb_flights"), read_table("dcb_sector_entries")
    assert entries["flight_id"].is_in(flights["flight_id"].implode()).all() and (flights["n_entries"].sum() == entries.height)
    cases = read_table("dcb_cases").row(0, named=True)
    assert cases["case"] == "cap90" and cases["hotspots"] == read_table("dcb_hotspots").height > 0
    assert (read_table("dcb_hotspots").select((pl.col("demand") > pl.col("capacity")).all()).item())
    res = read_table("dcb_results")
    assert sorted(res["method"].unique()) == ["FCFS", "HCMARL", "MIRL", "optimum", "readout_only"] and res.height == 3 + 2 * 2
    opt = res.filter(pl.col("method") == "optimum").row(0, named=True)
    assert opt["hotspots_left"] == 0 and opt["gap_to_optimum"] == 0.0
    assert read_table("dcb_delays").height == 2 * 2 * flights.height
    summ = read_table("dcb_summary").filter((pl.col("method") == "MIRL") & (pl.col("metric") == "total_delay_min")).row(0, named=True)
    assert summ["n_seeds"] == 2 and summ["mean"] == res.filter(pl.col("method") == "MIRL")["total_delay_min"].mean()
    # HCMARL against MIRL (CMARL was not run), paired over the 2 seeds: the differences of dcb_results' rows
    comp = read_table("dcb_comparisons").filter(pl.col("metric") == "regulated_flights").row(0, named=True)
    by_seed = {m: res.filter(pl.col("method") == m).sort("seed")["regulated_flights"].to_numpy() for m in ("HCMARL", "MIRL")}
    assert (comp["reference"], comp["seeds"]) == ("MIRL", 2) and comp["mean_diff"] == (by_seed["HCMARL"] - by_seed["MIRL"]).mean()
    assert comp["p_two_sided"] in (0.5, 1.0)  # 2 seeds allow no smaller p
    # and the raw greedy policies against each other, before the read-out
    comp = read_table("dcb_comparisons").filter(pl.col("metric") == "policy_total_delay_min").row(0, named=True)
    by_seed = {m: res.filter(pl.col("method") == m).sort("seed")["policy_total_delay_min"].to_numpy() for m in ("HCMARL", "MIRL")}
    assert comp["mean_diff"] == (by_seed["HCMARL"] - by_seed["MIRL"]).mean()
    checks = {e.check_name: e.passed for e in result.get_asset_check_evaluations()}
    assert checks["demand_rows_accounted"] and checks["optimum_is_lower_bound"] and checks["entries_consistent"]
    # the default read-out repairs what the policies leave: no run with a hotspot; the raw greedy policy is reported beside it
    assert checks["learners_leave_no_hotspot"] and (res["hotspots_left"] == 0).all()
    meta = result.asset_materializations_for_node("dcb_delays")[0].metadata
    runs = {(r["method"], r["seed"]): r for r in meta["runs"].data}
    assert meta["readout"].value == "repair" and len(runs) == 4
    assert Path(meta["dcb_learning_curves_png"].value).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"  # the training curves, as a figure
    # the raw greedy policy, apart from the read-out, is in the tables: dcb_results' policy_* from dcb_delays' policy_delay_min
    # (hotspots counted over every entry) agree with the training run's own count and total
    learned = res.filter(pl.col("method").is_in(["MIRL", "HCMARL"]))
    for r in learned.iter_rows(named=True):
        run = runs[(r["method"], r["seed"])]
        assert (r["policy_hotspots_left"], r["policy_total_delay_min"], r["solution"]) == (
            run["greedy_hotspots_left"], run["greedy_total_delay_min"], run["solution"])
    assert learned["policy_hotspots_left"].sum() > 0  # 5 episodes: the policies leave hotspots, the read-out resolves them
    assert res.filter(~pl.col("method").is_in(["MIRL", "HCMARL"])).select("solution", "policy_hotspots_left", "policy_total_delay_min").null_count().row(0) == (3, 3, 3)
    checked = {e.check_name: e.metadata for e in result.get_asset_check_evaluations()}["learners_leave_no_hotspot"]
    assert checked["runs_whose_policy_leaves_hotspots"].value == (learned["policy_hotspots_left"] > 0).sum()
    md = result.asset_materializations_for_node("dcb_results")[0].metadata
    assert any(k.startswith("dcb_demand_capacity_cap90") for k in md) and "dcb_delay_histogram_cap90" in md
    assert "dcb_box_plots" in result.asset_materializations_for_node("dcb_summary")[0].metadata
    # the runs in parallel processes give what one process gives (every run seeds itself)
    parallel = read_table("dcb_delays")
    again = dg.materialize(ASSETS, selection=["dcb_delays"], resources={"io_manager": ParquetIOManager()}, run_config={"ops": {
        "dcb_delays": {"config": {"episodes": 5, "seeds": [0, 1], "methods": ["MIRL", "HCMARL"], "workers": 1}}}})
    assert again.success and read_table("dcb_delays").drop("runtime_s").equals(parallel.drop("runtime_s"))
