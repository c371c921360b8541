"""Asset checks of the DCB tables: schemas, row accounting, and the issue's targets."""

import dagster as dg
import polars as pl

from assets.checks import schema_checks
from models.dcb.train import METHODS
from warehouse.storage import read_table

TABLES = ["dcb_sectors", "dcb_flights", "dcb_sector_entries", "dcb_demand_rejects", "dcb_demand_summary", "dcb_cases",
          "dcb_hotspots", "dcb_reference", "dcb_delays", "dcb_results", "dcb_summary", "dcb_comparisons"]


@dg.asset_check(asset="dcb_demand_summary", description="nothing silently dropped: read = kept + rejected, and the quarantine holds every rejected row")
def demand_rows_accounted() -> dg.AssetCheckResult:
    s = read_table("dcb_demand_summary")
    read, kept = (int(s.filter(pl.col("outcome") == o)["rows"].sum()) for o in ("read", "kept"))
    rejected = int(s.filter(pl.col("outcome") == "rejected")["rows"].sum())
    quarantined = read_table("dcb_demand_rejects").height
    return dg.AssetCheckResult(passed=read == kept + rejected and rejected == quarantined,
                               metadata={"read": read, "kept": kept, "rejected": rejected, "quarantined": quarantined})


@dg.asset_check(asset="dcb_sector_entries", description="every entry names a known flight and sector and exits no earlier than it enters")
def entries_consistent() -> dg.AssetCheckResult:
    e = read_table("dcb_sector_entries")
    bad = e.filter(~pl.col("sector").is_in(read_table("dcb_sectors")["sector"].implode())
                   | ~pl.col("flight_id").is_in(read_table("dcb_flights")["flight_id"].implode())
                   | (pl.col("exit_ts") < pl.col("entry_ts")))
    return dg.AssetCheckResult(passed=bad.is_empty(), metadata={"entries": e.height, "inconsistent": bad.height})


@dg.asset_check(asset="dcb_results", description="the optimum and FCFS leave no hotspot, and no run has less total delay than the optimum")
def optimum_is_lower_bound() -> dg.AssetCheckResult:
    r = read_table("dcb_results")
    ref_hot = r.filter(pl.col("method").is_in(["optimum", "FCFS"]) & (pl.col("hotspots_left") > 0)).height
    below = r.filter((pl.col("hotspots_left") == 0) & (pl.col("gap_to_optimum") < -1e-9)).height
    return dg.AssetCheckResult(passed=ref_hot == 0 and below == 0, metadata={"reference_runs_with_hotspots": ref_hot, "runs_below_optimum": below})


@dg.asset_check(asset="dcb_results", description="issue target: every learner leaves zero hotspots on every case "
                 "(the returned schedules; how many the raw policies leave before the read-out is reported beside)")
def learners_leave_no_hotspot() -> dg.AssetCheckResult:
    r = read_table("dcb_results").filter(pl.col("method").is_in(list(METHODS)))
    bad = r.filter(pl.col("hotspots_left") > 0)
    return dg.AssetCheckResult(passed=bad.is_empty(), severity=dg.AssetCheckSeverity.WARN, metadata={
        "runs": r.height, "runs_with_hotspots": bad.height,
        "where": dg.MetadataValue.json(bad.select("case", "method", "seed", "hotspots_left").to_dicts()),
        "runs_whose_policy_leaves_hotspots": r.filter(pl.col("policy_hotspots_left") > 0).height})


@dg.asset_check(asset="dcb_summary", description="issue targets: HCMARL has fewer regulated flights than CMARL and MIRL, and mean total delay within 10 % of the optimum")
def hcmarl_targets() -> dg.AssetCheckResult:
    s = read_table("dcb_summary")
    mean = {(c, m, k): v for c, m, k, v in s.select("case", "method", "metric", "mean").iter_rows()}
    per_case = {}
    for case in s["case"].unique().sort():
        reg = {m: mean.get((case, m, "regulated_flights")) for m in ("HCMARL", "CMARL", "MIRL")}
        gap = mean.get((case, "HCMARL", "gap_to_optimum"))
        per_case[case] = {"regulated": reg, "hcmarl_gap": gap,
                          "fewer_regulated": None not in reg.values() and reg["HCMARL"] < min(reg["CMARL"], reg["MIRL"]),
                          "within_10pct": gap is not None and gap <= 0.10}
    ok = bool(per_case) and all(v["fewer_regulated"] and v["within_10pct"] for v in per_case.values())
    return dg.AssetCheckResult(passed=ok, severity=dg.AssetCheckSeverity.WARN, metadata={"per_case": dg.MetadataValue.json(per_case)})


CHECKS = [*schema_checks(TABLES), demand_rows_accounted, entries_consistent, optimum_is_lower_bound, learners_leave_no_hotspot, hcmarl_targets]
