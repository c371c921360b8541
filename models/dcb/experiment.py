"""The DCB experiment as pure transforms for the assets: demand + sectorisation -> entries, cases,
problems, solutions -> metrics and thesis-style summaries (Tables 5.1-5.3)."""

from pathlib import Path

import numpy as np
import polars as pl

from models.aviation.ingest import summarise
from models.dcb.airspace import GeoJSONSectorisation, GridSectorisation, SectorFileError, sector_entries
from models.dcb.cmarl import peer_edges
from models.dcb.demand import DemandError, adsb_demand, so6_demand
from models.markdown import markdown_table
from models.stats import paired_comparisons
from models.dcb.problem import DELAY_COST_EUR_PER_MIN, REGULATED_MIN, DCBProblem, aircraft_class, base_capacities, hotspot_table, scaled_capacities
from models.dcb.train import TrainResult

METRICS = ("avg_delay_min", "regulated_flights", "total_delay_min", "hotspots_left", "gap_to_optimum", "runtime_s",
           "policy_hotspots_left", "policy_total_delay_min")
# the claims about HCMARL, paired over seeds: (method, reference) and the metrics compared
COMPARISONS = (("HCMARL", "CMARL"), ("HCMARL", "MIRL"))
# and the same for the raw greedy policies, before the read-out (policy_*): which learner's own schedule is better
COMPARED_METRICS = ("regulated_flights", "total_delay_min", "avg_delay_min", "gap_to_optimum", "policy_hotspots_left", "policy_total_delay_min")


def load_demand(path: str | Path, min_points: int = 6, so6_step_s: float = 30.0):
    """ADS-B/traffic table (foundation ingest) or SO6 file (by suffix .so6) -> (points, flights, rejects, summary).

    rejects: source, row_number, reason, detail; summary: source, outcome, reason, rows (read = kept + rejected)."""
    p = Path(path)
    if ".so6" in [s.lower() for s in p.suffixes[:-1]]:  # the ADS-B reader would call it an unsupported table type
        raise DemandError(f"{p}: SO6 files are read uncompressed, as .so6")
    if p.suffix.lower() == ".so6":
        points, flights, rej = so6_demand(p, so6_step_s)
        rejects = rej.select("source", row_number=pl.col("line_number").cast(pl.Int64), reason="reason", detail="line")
        read = len([ln for ln in p.read_text(errors="replace").splitlines() if ln.strip()])
        summary = summarise(p.name, read, read - rejects.height, dict(rejects.group_by("reason").len().iter_rows()))
    else:
        points, flights, rej, summary = adsb_demand(p, min_points)
        rejects = rej.select(
            "source", row_number=pl.col("row_index").cast(pl.Int64), reason="reason",
            detail=pl.concat_str(pl.col("icao24"), pl.col("callsign"), pl.col("ts").dt.to_string("%Y-%m-%dT%H:%M:%S"), separator=" ", ignore_nulls=True),
        )
    flights = flights.with_columns(aircraft_class=aircraft_class(pl.col("aircraft_type")))
    return points, flights, rejects, summary


def sectorisation(geojson_path: str | None, cell_lat_deg: float, cell_lon_deg: float, fl_edges: list[float], box: list[float] | None):
    """A user GeoJSON if given, else the grid (box = [lat_min, lat_max, lon_min, lon_max], None = the Swiss box)."""
    if geojson_path:
        return GeoJSONSectorisation(geojson_path)
    if box is not None and len(box) != 4:
        raise SectorFileError(f"grid sectorisation: box {box} must be [lat_min, lat_max, lon_min, lon_max]")
    extent = dict(zip(("lat_min", "lat_max", "lon_min", "lon_max"), box)) if box else {}
    return GridSectorisation(cell_lat_deg=cell_lat_deg, cell_lon_deg=cell_lon_deg, fl_edges=tuple(fl_edges), **extent)


def airspace_tables(points: pl.DataFrame, flights: pl.DataFrame, sectoriser) -> tuple[pl.DataFrame, pl.DataFrame, pl.DataFrame]:
    """-> (sectors with base capacity, flights with cost and entry count, sector entries)."""
    sectors = sectoriser.sectors()
    entries = sector_entries(points, sectoriser)
    if entries.is_empty():  # nothing to balance; most often SO6 in degrees, a GeoJSON written [lat, lon] or levels in feet
        where = getattr(sectoriser, "path", "the grid sectorisation")
        raise SectorFileError(f"{where}: none of the {flights.height} flights enters any of its {sectors.height} sectors: "
                              f"the flights lie at {_extent(points, ('lat', 'lat'), ('lon', 'lon'), ('fl', 'fl'))}; "
                              f"the sectors at {_extent(sectors, ('lat_min_deg', 'lat_max_deg'), ('lon_min_deg', 'lon_max_deg'), ('fl_lower', 'fl_upper'))} "
                              "(SO6 positions are decimal minutes of arc; GeoJSON positions are [lon, lat], fl_lower/fl_upper flight levels)")
    base = base_capacities(entries, sectors)
    sectors = sectors.with_columns(base_capacity_per_h=pl.col("sector").replace_strict(base, return_dtype=pl.Int64))
    n = entries.group_by("flight_id").agg(n_entries=pl.len().cast(pl.Int64))
    flights = flights.join(n, on="flight_id", how="left").select(
        "flight_id", "callsign", "aircraft_type", "aircraft_class",
        delay_cost_eur_per_min=pl.col("aircraft_class").replace_strict(DELAY_COST_EUR_PER_MIN, return_dtype=pl.Float64),
        n_entries=pl.col("n_entries").fill_null(0),
    )
    return sectors, flights, entries.sort("flight_id", "entry_ts")


def _extent(t: pl.DataFrame, lat: tuple[str, str], lon: tuple[str, str], fl: tuple[str, str]) -> str:
    """'lat a..b, lon c..d, FL e..f' over a table's (lower, upper) columns: where flights or sectors are, for an error line."""
    lo = t.select(pl.col(c[0]).min() for c in (lat, lon, fl)).row(0)
    hi = t.select(pl.col(c[1]).max() for c in (lat, lon, fl)).row(0)
    return ", ".join(f"{name} {round(a, 2):g}..{round(b, 2):g}" for name, a, b in zip(("lat", "lon", "FL"), lo, hi))


def case_name(scale: float) -> str:
    return f"cap{round(scale * 100):d}"


def build_problem(entries: pl.DataFrame, sectors: pl.DataFrame, flights: pl.DataFrame, scale: float, max_delay_min: int) -> DCBProblem:
    """The DCB problem of one case: every flight of the day is an agent (flights with no entry never act)."""
    base = dict(sectors.select("sector", "base_capacity_per_h").iter_rows())
    return DCBProblem(entries, scaled_capacities(base, scale), flights, max_delay_min)


def case_row(case: str, scale: float, problem: DCBProblem) -> dict:
    """Table 5.1's description of a case before any delay."""
    zero = np.zeros(problem.n_flights, dtype=np.int64)
    ev = problem.evaluate(zero)
    _, _, degree, _ = peer_edges(ev, problem.n_flights)
    in_hot = ev.hotspots_per_flight > 0
    return {"case": case, "capacity_scale": scale, "max_delay_min": problem.max_delay_min, "n_flights": problem.n_flights,
            "hotspots": ev.hotspots, "flights_in_hotspots": int(in_hot.sum()),
            "avg_traffic_density": float(degree[in_hot].mean()) if in_hot.any() else 0.0}


def hotspots_before(case: str, problem: DCBProblem) -> pl.DataFrame:
    t = hotspot_table(problem, np.zeros(problem.n_flights, dtype=np.int64))
    return t.filter("is_hotspot").select(pl.lit(case).alias("case"), "sector", "hour", "demand", "capacity")


def delay_rows(case: str, method: str, seed: int, problem: DCBProblem, delay_min: np.ndarray, runtime_s: float,
               policy: TrainResult | None = None) -> pl.DataFrame:
    """One row per flight of a solution; a learner's (`policy`: its TrainResult) also carries which candidate was returned,
    the raw greedy policy's own delay of the flight and the training episodes (dcb_delays)."""
    df = pl.DataFrame({"flight_id": problem.flight_ids, "delay_min": delay_min.astype(np.int64)}).select(
        case=pl.lit(case), method=pl.lit(method), seed=pl.lit(seed, pl.Int64), flight_id="flight_id", delay_min="delay_min",
        runtime_s=pl.lit(float(runtime_s)))
    if policy is None:
        return df
    return df.with_columns(episodes=pl.lit(policy.episodes, pl.Int64), solution=pl.lit(policy.source),
                           policy_delay_min=pl.Series(policy.greedy_delay.astype(np.int64)))


def curve_rows(case: str, method: str, seed: int, run: TrainResult) -> pl.DataFrame:
    """The run's training curve (every 50th episode: hotspots left, total delay) as rows, for the learning-curve figure."""
    return pl.DataFrame(run.curve, schema=["episode", "hotspots_left", "total_delay_min"], orient="row").with_columns(
        case=pl.lit(case), method=pl.lit(method), seed=pl.lit(seed))


def results(delays: pl.DataFrame, problems: dict, optimum_total: dict) -> pl.DataFrame:
    """dcb_delays and dcb_reference rows (diagonal concat: the references have no solution / policy_delay_min) -> one
    metrics row per (case, method, seed); a learner's row also has its raw greedy policy's hotspots and total delay, the
    references' are null."""
    rows = []
    for (case, method, seed), g in delays.group_by("case", "method", "seed", maintain_order=True):
        problem = problems[case]
        d = g.join(pl.DataFrame({"flight_id": problem.flight_ids}), on="flight_id", how="right")
        delay = d["delay_min"].fill_null(0).to_numpy()
        reg = delay >= REGULATED_MIN
        opt = optimum_total.get(case)
        policy = d["policy_delay_min"].fill_null(0).to_numpy() if g["policy_delay_min"].is_not_null().all() else None
        rows.append({
            "case": case, "method": method, "seed": seed,
            "avg_delay_min": float(delay[reg].sum() / problem.n_flights), "regulated_flights": int(reg.sum()),
            "hotspots_left": problem.evaluate(delay, all_entries=True).hotspots, "total_delay_min": int(delay.sum()),
            "max_delay_min": int(delay.max()),
            "gap_to_optimum": (delay.sum() - opt) / opt if opt else None, "runtime_s": float(g["runtime_s"][0]),
            "solution": g["solution"][0],
            "policy_hotspots_left": None if policy is None else problem.evaluate(policy, all_entries=True).hotspots,
            "policy_total_delay_min": None if policy is None else int(policy.sum()),
        })
    return pl.DataFrame(rows, schema_overrides={"gap_to_optimum": pl.Float64, "seed": pl.Int64, "solution": pl.String,
                                                "policy_hotspots_left": pl.Int64, "policy_total_delay_min": pl.Int64})


def summary(results_df: pl.DataFrame) -> pl.DataFrame:
    """Mean, std, median, IQR over seeds per case, method and metric (Tables 5.2-5.3)."""
    long = results_df.unpivot(index=["case", "method", "seed"], on=list(METRICS), variable_name="metric").drop_nulls("value")
    return long.group_by("case", "method", "metric", maintain_order=True).agg(
        n_seeds=pl.len().cast(pl.Int64), mean=pl.col("value").mean(), std=pl.col("value").std(), median=pl.col("value").median(),
        iqr=pl.col("value").quantile(0.75, "linear") - pl.col("value").quantile(0.25, "linear"),
    ).with_columns(pl.col("mean", "std", "median", "iqr").cast(pl.Float64))


def comparisons(results_df: pl.DataFrame) -> pl.DataFrame:
    """COMPARISONS per case, paired over the training seeds both learners ran (models.stats.paired_comparisons)."""
    return paired_comparisons(results_df, "case", COMPARISONS, COMPARED_METRICS)


def summary_markdown(summ: pl.DataFrame, metrics=("avg_delay_min", "regulated_flights", "total_delay_min", "hotspots_left", "gap_to_optimum",
                                                 "policy_hotspots_left")) -> str:
    """Tables 5.2/5.3-style markdown: one table per metric, rows case x method."""
    out = []
    for m in metrics:
        t = summ.filter(pl.col("metric") == m)
        if t.is_empty():
            continue
        rows = t.select("case", "method", n="n_seeds", mean="mean", std="std", median="median", IQR="iqr")
        out += [f"**{m}** (over seeds)", "", markdown_table(rows, cell=lambda v: "" if v is None else f"{v:.3f}" if isinstance(v, float) else str(v))]
    return "\n".join(out)
