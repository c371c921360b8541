"""Tables of the air traffic congestion / DCB system (issue 5, thesis chapter 5)."""

import pyarrow as pa

from warehouse.table import TS, Table, col, comparison_columns

_CASE = col("case", pa.string(), "", "evaluation case, e.g. cap90 = every sector at 90 % of its base capacity")
_METHOD = col("method", pa.string(), "", "MIRL, CMARL, HCMARL, stHMIRL, sHMIRL, tHMIRL (learners), optimum (integer program), FCFS or readout_only (the learners' read-out of zero delays)")
_SEED = col("seed", pa.int64(), "", "training seed (0 for the deterministic optimum, FCFS and readout_only)")
_FLIGHT = col("flight_id", pa.string(), "", "flight key (foundation ingest's callsign_icao24_start, or the SO6 flight key)")
_SECTOR = col("sector", pa.string(), "", "sector name (grid: R<row>C<col>_FL<lower>-<upper>)")
_DELAY = col("delay_min", pa.int64(), "min", "ground delay given to the flight (whole minutes; shifts its whole schedule)")
_RUNTIME = col("runtime_s", pa.float64(), "s", "wall time of the run that produced this solution (training or solve)")
_SOLUTION = col("solution", pa.string(), "", "the candidate delay_min was read out of: greedy (the final policy's rollout) or "
                "best_episode (the best ground-level training episode), each repaired and trimmed unless readout=best_episode")

TABLES: list[Table] = [
    Table(
        "dcb_sectors",
        "Sectorisation: lateral cells x flight-level bands (or the user's GeoJSON polygons) with the base hourly capacity.",
        (
            _SECTOR,
            col("lat_min_deg", pa.float64(), "deg", "southern edge (bounding box for polygons)"),
            col("lat_max_deg", pa.float64(), "deg", "northern edge (bounding box for polygons)"),
            col("lon_min_deg", pa.float64(), "deg", "western edge (bounding box for polygons)"),
            col("lon_max_deg", pa.float64(), "deg", "eastern edge (bounding box for polygons)"),
            col("fl_lower", pa.float64(), "FL", "lowest flight level inside the sector (inclusive)"),
            col("fl_upper", pa.float64(), "FL", "flight level where the sector ends (exclusive)"),
            col("geometry_geojson", pa.string(), "", "GeoJSON Polygon of a user sector file; null for grid cells", nullable=True),
            col("capacity_per_h", pa.int64(), "entries/h", "capacity given in the sector file; null when none was given", nullable=True),
            col("base_capacity_per_h", pa.int64(), "entries/h",
                "capacity before case scaling: the file's, else the sector's peak hourly entry count in the undelayed demand"),
        ),
    ),
    Table(
        "dcb_flights",
        "Flights of the demand day: one row per flight with its aircraft class and strategic delay cost.",
        (
            _FLIGHT,
            col("callsign", pa.string(), "", "callsign", nullable=True),
            col("aircraft_type", pa.string(), "", "ICAO type designator (SO6); null for ADS-B, which carries none", nullable=True),
            col("aircraft_class", pa.string(), "", "delay cost class: turboprop, regional_jet, narrowbody, widebody or unknown"),
            col("delay_cost_eur_per_min", pa.float64(), "EUR/min", "strategic ground delay cost per minute of the class (docs/dcb.md)"),
            col("n_entries", pa.int64(), "", "sector entries of the flight (0: never inside the sectorised airspace)"),
        ),
    ),
    Table(
        "dcb_sector_entries",
        "Sector entry/exit events of every flight, undelayed: a visit starts at the first point inside the sector.",
        (
            _FLIGHT,
            _SECTOR,
            col("entry_ts", TS, "UTC", "time of the first point inside the sector"),
            col("exit_ts", TS, "UTC", "time of the first point of the next visit (or the flight's last point)"),
        ),
    ),
    Table(
        "dcb_demand_rejects",
        "Quarantine of the demand input: every row or SO6 line not used, with its reason. kept + rejected = read.",
        (
            col("source", pa.string(), "", "input file name"),
            col("row_number", pa.int64(), "", "SO6: 1-based line number; ADS-B: 0-based row index in the input file"),
            col("reason", pa.string(), "", "SO6: wrong_field_count, bad_number, bad_time_or_date, time_reversed, out_of_range; "
                "ADS-B: the foundation ingest's reasons"),
            col("detail", pa.string(), "", "the SO6 line as read, or icao24/callsign/time of the ADS-B row", nullable=True),
        ),
    ),
    Table(
        "dcb_demand_summary",
        "Row accounting of the demand input: read = kept + rejected per reason.",
        (
            col("source", pa.string(), "", "input file name"),
            col("outcome", pa.string(), "", "read, kept or rejected"),
            col("reason", pa.string(), "", "reject reason; empty for read and kept"),
            col("rows", pa.int64(), "", "rows (ADS-B state vectors) or lines (SO6)"),
        ),
    ),
    Table(
        "dcb_cases",
        "Evaluation cases of increasing difficulty (capacity scalings), described like thesis Table 5.1.",
        (
            _CASE,
            col("capacity_scale", pa.float64(), "", "every sector's capacity = max(1, floor(scale x base capacity))"),
            col("max_delay_min", pa.int64(), "min", "MaxDelay: largest ground delay a learner may give"),
            col("n_flights", pa.int64(), "", "flights of the day (agents)"),
            col("hotspots", pa.int64(), "", "overloaded sector-hours before any delay"),
            col("flights_in_hotspots", pa.int64(), "", "flights with an entry in a hotspot before any delay"),
            col("avg_traffic_density", pa.float64(), "", "mean number of peers (flights sharing a hotspot) of a flight in a hotspot"),
        ),
    ),
    Table(
        "dcb_hotspots",
        "Hotspots before any delay: sector-hours whose entry count exceeds the hourly capacity.",
        (
            _CASE,
            _SECTOR,
            col("hour", TS, "UTC", "start of the hour"),
            col("demand", pa.int64(), "entries/h", "entries into the sector during the hour"),
            col("capacity", pa.int64(), "entries/h", "hourly capacity of the sector in this case"),
        ),
    ),
    Table(
        "dcb_reference",
        "Reference solutions: the exact minimum-total-delay integer program (HiGHS) and first-come-first-served delays.",
        (_CASE, _METHOD, _SEED, _FLIGHT, _DELAY, _RUNTIME),
    ),
    Table(
        "dcb_delays",
        "Ground delay of every flight in the solution read out of every learner, case and seed: its greedy rollout or best "
        "training episode, hotspots left repaired FCFS and unneeded delay trimmed unless readout=best_episode (docs/dcb.md).",
        (_CASE, _METHOD, _SEED, _FLIGHT, _DELAY, _RUNTIME,
         col("episodes", pa.int64(), "", "training episodes over all abstraction levels"),
         _SOLUTION,
         col("policy_delay_min", pa.int64(), "min", "the flight's delay in the greedy (ε = 0) rollout of the final policy, before any "
             "read-out: the learned policy's own schedule, whichever candidate delay_min comes from")),
    ),
    Table(
        "dcb_results",
        "Metrics per case, method and seed (thesis Tables 5.2-5.3 measures); delays under 4 min are ignored in "
        "avg_delay_min and regulated_flights, as the thesis does.",
        (
            _CASE, _METHOD, _SEED,
            col("avg_delay_min", pa.float64(), "min", "sum of delays >= 4 min divided by all flights of the day"),
            col("regulated_flights", pa.int64(), "", "flights with a delay >= 4 min"),
            col("hotspots_left", pa.int64(), "", "overloaded sector-hours after the delays"),
            col("total_delay_min", pa.int64(), "min", "sum of all delays"),
            col("max_delay_min", pa.int64(), "min", "largest delay"),
            col("gap_to_optimum", pa.float64(), "fraction",
                "(total_delay_min - optimum's) / optimum's; null when the optimum is 0 or the case has none", nullable=True),
            _RUNTIME,
            col("solution", pa.string(), "", "learners: " + _SOLUTION.description + "; null for the references", nullable=True),
            col("policy_hotspots_left", pa.int64(), "", "overloaded sector-hours the learned policy's own schedule (dcb_delays' "
                "policy_delay_min) leaves, before the read-out: the issue's zero-hotspot target judged on the policy; null for "
                "the references", nullable=True),
            col("policy_total_delay_min", pa.int64(), "min", "sum of policy_delay_min; null for the references", nullable=True),
        ),
    ),
    Table(
        "dcb_comparisons",
        "HCMARL against CMARL and against MIRL per case, paired over training seeds (exact sign-flip test): the issue's "
        "\"HCMARL has fewer regulated flights than CMARL and MIRL\" as a test.",
        (
            _CASE,
            *comparison_columns("HCMARL", "CMARL or MIRL", "regulated_flights, total_delay_min (min), avg_delay_min (min), "
                                "gap_to_optimum (fraction), or the raw greedy policy's policy_hotspots_left and "
                                "policy_total_delay_min (min), as in dcb_results"),
        ),
    ),
    Table(
        "dcb_summary",
        "Mean, std, median and IQR over seeds per case, method and metric (as thesis Tables 5.2-5.3).",
        (
            _CASE, _METHOD,
            col("metric", pa.string(), "", "avg_delay_min, regulated_flights, total_delay_min, hotspots_left, gap_to_optimum, runtime_s, "
                "policy_hotspots_left or policy_total_delay_min (dcb_results)"),
            col("n_seeds", pa.int64(), "", "seeds aggregated"),
            col("mean", pa.float64(), "metric's", "mean over seeds"),
            col("std", pa.float64(), "metric's", "sample standard deviation over seeds (null for one seed)", nullable=True),
            col("median", pa.float64(), "metric's", "median over seeds"),
            col("iqr", pa.float64(), "metric's", "interquartile range (75th - 25th percentile, linear interpolation)"),
        ),
    ),
]
