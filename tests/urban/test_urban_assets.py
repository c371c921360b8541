"""Dagster assets on the real bundled networks: routes and scenario copies, SUMO baselines, thesis tables."""

from pathlib import Path

import dagster as dg
import polars as pl

from assets.urban.scenarios import urban_routes, urban_scenarios
from models.urban.experiments import evaluation_jobs, results_rows, run_job, thesis_markdown, thesis_tables
from warehouse.io_manager import ParquetIOManager
from warehouse.storage import read_table


def test_scenario_assets_and_baselines(isolated_home):
    result = dg.materialize([urban_routes, urban_scenarios], resources={"io_manager": ParquetIOManager()})
    assert result.success
    routes, scen = read_table("urban_routes"), read_table("urban_scenarios")
    counts = dict(routes.group_by("network").len().iter_rows())
    assert counts["sc1"] == 12 and 5 <= counts["real"] <= 20  # the demo keeps real routes of <= 600 m, at most 20
    assert routes.filter(pl.col("network") == "real")["length_m"].max() <= 600.0
    assert set(scen["role"]) == {"train", "eval", "reuse"}
    assert scen.filter(pl.col("role") == "train")["demand_seed"].is_in(scen.filter(pl.col("role") != "train")["demand_seed"].implode()).sum() == 0
    assert all(Path(p).exists() for p in scen["routes_path"])
    row = scen.filter(pl.col("scenario") == "sc1_x3").row(0, named=True)
    assert row["n_vehicles"] == 120 and row["policy_scenario"] == "sc1" and row["role"] == "reuse"
    assert (scen["n_cars"] + scen["n_buses"] + scen["n_trucks"] == scen["n_vehicles"]).all()

    sc1_eval = scen.filter((pl.col("scenario") == "sc1") & (pl.col("role") == "eval"))
    jobs = evaluation_jobs(sc1_eval, {}, ["idm", "krauss"])
    results = results_rows([k for k, _ in jobs], [run_job(j) for _, j in jobs])
    assert results.height == 2 * sc1_eval.height
    assert (results["collisions"] >= 0).all() and results["avg_travel_time_s"].is_not_null().all()
    assert results.filter(pl.col("method") == "idm")["arrived"].sum() > 0
    tables = thesis_tables(results, scen)
    assert set(tables["thesis_table"]) == {"3.2", "4.3"}
    assert tables.filter(pl.col("thesis_table") == "3.2")["method"].sort().to_list() == ["idm", "krauss"]
    assert "**Table 3.2**" in thesis_markdown(tables)
