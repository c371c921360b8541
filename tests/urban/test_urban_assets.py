"""Dagster assets on the real bundled networks: routes and scenario copies, SUMO baselines, thesis tables."""

from pathlib import Path

import dagster as dg
import polars as pl

from assets.urban.scenarios import urban_routes, urban_scenarios
from assets.urban.training import urban_training
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


def test_training_asset_skips_runs_finished_before_a_failure_and_removes_its_checkpoints(isolated_home):
    io = {"io_manager": ParquetIOManager()}
    assert dg.materialize([urban_routes, urban_scenarios], resources=io).success
    train = read_table("urban_scenarios").filter(pl.col("role") == "train")
    first, later = train["scenario"].unique(maintain_order=True).to_list()[:2]
    routes = Path(train.filter(pl.col("scenario") == later)["routes_path"][0])
    good = routes.read_bytes()
    routes.write_text("<routes><vehicle")  # the later scenario's first copy fails once the first scenario is trained
    config = {"episodes": 2, "seeds": [0], "methods": ["col_marl"], "workers": 1, "gradient_steps": 2}
    assets = [dg.AssetSpec("urban_routes"), dg.AssetSpec("urban_scenarios"), urban_training]
    instance = dg.DagsterInstance.ephemeral()
    failed = dg.materialize(assets, run_config={"ops": {"urban_training": {"config": config}}}, resources=io, instance=instance,
                            raise_on_error=False)
    assert not failed.success
    assert [p.name for p in (isolated_home / "checkpoints").iterdir()] == [f"urban_{first}_col_marl_seed0.ckpt"]
    routes.write_bytes(good)
    # the same command again, networks and copies made anew (SUMO stamps each file with its time): the checkpoint still holds
    done = dg.materialize([urban_routes, urban_scenarios, urban_training], run_config={"ops": {"urban_training": {"config": config}}},
                          resources=io, instance=instance)
    messages = [e.user_message for e in instance.all_logs(done.run_id)]
    assert any(m.endswith(f"{first} seed 0: col: trained already ({isolated_home / 'checkpoints'}/urban_{first}_col_marl_seed0.ckpt)")
               for m in messages)
    assert not any(f"{later} seed 0: col: trained already" in m for m in messages)
    assert list((isolated_home / "checkpoints").iterdir()) == []
    log = read_table("urban_training")
    assert sorted(log["scenario"].unique()) == sorted([first, later]) and set(log["episode"]) == {0, 1}
    assert all(Path(p).is_file() for p in log["model_path"].unique())
    curves = done.asset_materializations_for_node("urban_training")[0].metadata["urban_training_curves_png"].value
    assert Path(curves).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"  # the learning curves of both scenarios, as a figure
