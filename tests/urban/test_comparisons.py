"""urban_comparisons: paired differences over training seeds on the copies both methods ran, through Dagster and the
warehouse's schema."""

import dagster as dg
import polars as pl
import pytest

from assets.urban.evaluation import urban_comparisons
from models.urban.experiments import comparisons
from warehouse.io_manager import ParquetIOManager
from warehouse.storage import read_table, write_table


def results(rows):
    """urban_results rows from (scenario, copy, method, seed, collisions, success, travel time s)."""
    return pl.DataFrame([
        {"scenario": s, "copy": c, "method": m, "seed": k, "avg_travel_time_s": t, "avg_speed_mps": 20.0, "avg_fuel_mlps": 1.0,
         "collisions": n, "teleports": 0, "arrived": 40, "n_vehicles": 40, "success": ok}
        for s, c, m, k, n, ok, t in rows], schema_overrides={"avg_travel_time_s": pl.Float64})


# i-MARL collides more on every seed; seed 2's copy 3 was run by i-MARL only (not a pair); IDM is in no compared pair
ROWS = [
    ("sc1", 2, "col_marl", 0, 0, True, 16.0), ("sc1", 3, "col_marl", 0, 1, False, 17.0),
    ("sc1", 2, "i_marl", 0, 1, False, 18.0), ("sc1", 3, "i_marl", 0, 2, False, None),
    ("sc1", 2, "col_marl", 1, 0, True, 16.0), ("sc1", 3, "col_marl", 1, 0, True, 16.0),
    ("sc1", 2, "i_marl", 1, 0, True, 15.0), ("sc1", 3, "i_marl", 1, 2, False, 17.0),
    ("sc1", 2, "col_marl", 2, 0, True, 16.0),
    ("sc1", 2, "i_marl", 2, 3, False, 20.0), ("sc1", 3, "i_marl", 2, 9, False, 20.0),
    ("sc1", 2, "idm", 0, 0, True, 35.0),
]


def test_paired_differences_over_seeds_on_shared_copies():
    df = comparisons(results(ROWS))
    assert set(df["method"]) == {"i_marl"} and set(df["reference"]) == {"col_marl"}
    c = df.filter(pl.col("metric") == "collisions").row(0, named=True)
    # per seed (copies both ran): seed 0 (1+2)/2 - (0+1)/2 = 1, seed 1 (0+2)/2 - 0 = 1, seed 2 (copy 2 only) 3 - 0 = 3
    assert c["seeds"] == 3
    assert c["mean_diff"] == pytest.approx(5 / 3) and c["std_diff"] == pytest.approx(pl.Series([1.0, 1.0, 3.0]).std())
    assert (c["seeds_higher"], c["seeds_lower"]) == (3, 0)
    assert c["p_two_sided"] == pytest.approx(2 / 8)  # 3 seeds, all higher: the smallest p three seeds allow
    s = df.filter(pl.col("metric") == "success").row(0, named=True)
    assert s["mean_diff"] == pytest.approx(((0 - 0.5) + (0.5 - 1) + (0 - 1)) / 3) and s["seeds_lower"] == 3
    t = df.filter(pl.col("metric") == "avg_travel_time_s").row(0, named=True)
    # seed 0: i-MARL's copy 3 has no arrival (null), so copy 3 counts on neither side: 18.0 against 16.0
    assert t["seeds"] == 3 and t["method_mean"] == pytest.approx((18.0 + 16.0 + 20.0) / 3) and t["reference_mean"] == pytest.approx(16.0)
    assert df.filter(pl.col("metric") == "teleports")["p_two_sided"].to_list() == [1.0]  # no difference at all


def test_one_seed_is_a_difference_with_p_one_and_no_std():
    df = comparisons(results([r for r in ROWS if r[3] == 0]))
    c = df.filter(pl.col("metric") == "collisions").row(0, named=True)
    assert c["seeds"] == 1 and c["std_diff"] is None and c["p_two_sided"] == 1.0


def test_asset_writes_the_declared_table(isolated_home):
    write_table("urban_results", results(ROWS))
    result = dg.materialize([dg.AssetSpec("urban_results"), urban_comparisons],
                            resources={"io_manager": ParquetIOManager()})
    assert result.success
    stored = read_table("urban_comparisons")
    assert stored.height == 4 and stored["p_two_sided"].is_between(0, 1).all()
    md = result.asset_materializations_for_node("urban_comparisons")[0].metadata["comparisons"].value
    assert "i_marl" in md and "p_two_sided" in md


def test_no_pair_evaluated_gives_an_empty_table_of_the_declared_columns():
    df = comparisons(results([r for r in ROWS if r[2] == "idm"]))
    assert df.is_empty() and "p_two_sided" in df.columns
