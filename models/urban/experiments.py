"""The experiments of chapters 3-4 as data: networks, scenarios per profile, training and evaluation runs,
and the thesis's result tables computed from our evaluation rows. No Dagster here.

Copies: every scenario has seeded copies; `train` copies feed training episodes, `eval` copies (other
seeds) are only ever evaluated, `reuse` copies (2-5x vehicles and duration, §4.4) too.
"""

import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl

from models.stats import paired_comparisons
from models.urban.network import UrbanInputError, artificial_network, enumerate_routes, junction_census, osm_network, sumo_network
from models.urban.scenarios import Demand, write_copy
from models.urban.sim import ScenarioFiles

REPO = Path(__file__).resolve().parents[2]
REAL_NET = REPO / "data" / "sumo" / "bologna_acosta.net.xml.gz"
METHODS_RL = {"col_marl": "col", "i_marl": "ind", "ch3_dqn_cnn": "ch3"}  # method -> models.urban.col_marl variant
METHODS_SUMO = {"idm": "IDM", "krauss": "Krauss"}
# evaluation-only methods: a trained method's policies driven through the env's optional safety layer (models.urban.env.shield_masks),
# reported as their own rows next to the learned policy's
METHODS_SHIELDED = {"col_marl_shield": "col_marl"}
# every method urban_results can evaluate, in the order of its rows (the shielded method next to the one it drives)
EVALUATION_METHODS = ["col_marl", "col_marl_shield", "i_marl", "ch3_dqn_cnn", "idm", "krauss"]
EVAL_EPISODE_SEED = 7919  # SUMO seed of a held-out copy's evaluation episode: this + the copy number, for every method and policy seed


@dataclass(frozen=True)
class NetworkSpec:
    name: str
    source: str  # "grid:<n>" (netgenerate), a .net.xml[.gz] or an .osm[.gz] path
    max_speed_mps: float
    max_routes: int
    max_route_length_m: float = float("inf")


@dataclass(frozen=True)
class ScenarioSpec:
    name: str
    network: str
    demand: Demand
    train_copies: int
    eval_copies: int
    policy_scenario: str  # == name: trained on its own train copies; else evaluated with that scenario's policies
    role: str = "eval"  # role of the non-training copies: eval or reuse


def networks(profile: str, user_source: str | None = None) -> list[NetworkSpec]:
    """Sc1/Sc2/Sc4 (40 m/s, Table 4.2's 12/24/32 routes), the bundled real network (30 m/s) and an optional user network."""
    # §4.3.4: nearly 150 route agents; the demo keeps 20 routes of at most 600 m to train in minutes
    real_routes, real_length = (20, 600.0) if profile == "demo" else (150, float("inf"))
    nets = [NetworkSpec("sc1", "grid:1", 40.0, 12), NetworkSpec("real", str(REAL_NET), 30.0, real_routes, real_length)]
    if profile != "demo":
        nets += [NetworkSpec("sc2", "grid:2", 40.0, 24), NetworkSpec("sc4", "grid:4", 40.0, 32)]
    if user_source:
        nets.append(NetworkSpec("user", user_source, 30.0, real_routes, real_length))
    return nets


def scenarios(profile: str, user_network: bool = False, artificial_cars_only: bool = False) -> list[ScenarioSpec]:
    """Demo: Sc1 and the real network (CR) trained; MR/LR noise and 3x denser/longer copies evaluated with
    their policies. Paper: Tables 4.2-4.9 (Sc1/Sc2/Sc4, real CR/MR/LR, LS_const/LS_noisy, knowledge reuse).
    Every scenario carries the 75/15/10 mix; artificial_cars_only: passenger cars only on Sc1/Sc2/Sc4 and their copies,
    as Table 4.2's route-agent counts suggest the thesis had (models.urban.scenarios.CARS_ONLY)."""
    cars = artificial_cars_only
    if profile == "demo":
        s = [
            ScenarioSpec("sc1", "sc1", Demand(40, 160.0, cars_only=cars), 2, 3, "sc1"),
            ScenarioSpec("real_cr", "real", Demand(40, 160.0), 2, 3, "real_cr"),
            ScenarioSpec("real_mr", "real", Demand(40, 160.0, noise_sigma_s=0.5), 0, 3, "real_cr"),
            ScenarioSpec("real_lr", "real", Demand(40, 160.0, noise_sigma_s=1.0), 0, 3, "real_cr"),
            ScenarioSpec("sc1_x3", "sc1", Demand(120, 480.0, cars_only=cars), 0, 3, "sc1", "reuse"),
            ScenarioSpec("real_cr_x3", "real", Demand(120, 480.0), 0, 3, "real_cr", "reuse"),
        ]
    else:
        s = [
            ScenarioSpec("sc1", "sc1", Demand(150, 600.0, cars_only=cars), 5, 10, "sc1"),
            ScenarioSpec("sc2", "sc2", Demand(300, 1200.0, cars_only=cars), 5, 10, "sc2"),
            ScenarioSpec("sc4", "sc4", Demand(1000, 4000.0, cars_only=cars), 5, 10, "sc4"),
            *[ScenarioSpec(f"real_{k}", "real", Demand(300, 1200.0, noise_sigma_s=sd), 5, 10, f"real_{k}")
              for k, sd in (("cr", 0.0), ("mr", 0.5), ("lr", 1.0))],
            ScenarioSpec("real_ls_const", "real", Demand(0, 1800.0, "ls"), 5, 10, "real_ls_const"),
            ScenarioSpec("real_ls_noisy", "real", Demand(0, 1800.0, "ls", 0.2), 5, 10, "real_ls_noisy"),
            # Table 4.6-4.7: medium (2x) and large (5x) copies of the artificial scenarios
            *[ScenarioSpec(f"{sc}_x{k}", sc, Demand(n * k, d * k, cars_only=cars), 0, 10, sc, "reuse")
              for sc, n, d in (("sc1", 150, 600.0), ("sc2", 300, 1200.0), ("sc4", 1000, 4000.0)) for k in (2, 5)],
            # Table 4.8: each noise level's policies on the other noise levels
            *[ScenarioSpec(f"real_{k}_by_{p}", "real", Demand(300, 1200.0, noise_sigma_s=sd), 0, 10, f"real_{p}", "reuse")
              for k, sd in (("cr", 0.0), ("mr", 0.5), ("lr", 1.0)) for p in ("cr", "mr", "lr") if p != k],
            # Table 4.9: LS policies on 2x longer LS copies of the other noise type
            ScenarioSpec("real_ls_noisy_by_const_x2", "real", Demand(0, 3600.0, "ls", 0.2), 0, 10, "real_ls_const", "reuse"),
            ScenarioSpec("real_ls_const_by_noisy_x2", "real", Demand(0, 3600.0, "ls"), 0, 10, "real_ls_noisy", "reuse"),
        ]
    if user_network:
        s.append(ScenarioSpec("user", "user", Demand(40, 160.0) if profile == "demo" else Demand(300, 1200.0), 2, 3, "user"))
    return s


def build_network(spec: NetworkSpec, out_dir: Path) -> Path:
    out = out_dir / f"{spec.name}.net.xml"
    out_dir.mkdir(parents=True, exist_ok=True)
    if spec.source.startswith("grid:"):
        return artificial_network(int(spec.source.split(":")[1]), out, speed_mps=spec.max_speed_mps)
    if ".osm" in Path(spec.source).name:
        return osm_network(Path(spec.source), out, spec.max_speed_mps)
    return sumo_network(Path(spec.source), out, spec.max_speed_mps)


def routes_table(specs: list[NetworkSpec], out_dir: Path, seed: int) -> pl.DataFrame:
    """Build every network (unsignalized) and enumerate its routes: the rows of `urban_routes`."""
    frames = []
    for spec in specs:
        net = build_network(spec, out_dir)
        census = junction_census(net)
        routes = pl.DataFrame(enumerate_routes(net, spec.max_routes, seed, spec.max_route_length_m))
        frames.append(
            routes.rename({"n_junctions": "n_junctions_crossed"}).with_columns(
                network=pl.lit(spec.name), net_path=pl.lit(str(net)), source=pl.lit(spec.source),
                n_junctions=pl.lit(census.junctions, pl.Int64), max_speed_mps=pl.lit(spec.max_speed_mps),
            )
        )
    return pl.concat(frames).select(
        "network", "net_path", "source", "n_junctions", "max_speed_mps", "route_id", "edges", "length_m", "n_junctions_crossed"
    )


def training_frame(rows: list[dict], scenario: str, method: str, seed: int, model_path: str) -> pl.DataFrame:
    """urban_training rows of one policy set. An agent with no vehicle in an episode has no return, one with an empty
    buffer no loss: null, not NaN, so that SQL aggregates (avg) and the metadata's means skip them."""
    return pl.DataFrame(rows).with_columns(
        pl.col("return", "loss").fill_nan(None), scenario=pl.lit(scenario), method=pl.lit(method), seed=pl.lit(seed, pl.Int64),
        model_path=pl.lit(model_path),
    )


def demand_seed(scenario: str, copy: int) -> int:
    """Distinct, stable seeds per scenario and copy (train and eval copies never share one)."""
    return zlib.crc32(scenario.encode()) % 1_000_000 * 1000 + copy


def scenarios_table(specs: list[ScenarioSpec], routes: pl.DataFrame, out_dir: Path) -> pl.DataFrame:
    """Write every seeded copy's SUMO files: the rows of `urban_scenarios`."""
    rows = []
    for s in specs:
        net_routes = routes.filter(pl.col("network") == s.network)
        if net_routes.is_empty():
            continue
        route_dicts = net_routes.select("route_id", "edges").to_dicts()
        net_path, vmax = net_routes["net_path"][0], float(net_routes["max_speed_mps"][0])
        for copy in range(s.train_copies + s.eval_copies):
            seed = demand_seed(s.name, copy)
            info = write_copy(out_dir / s.name / f"copy{copy:02d}", Path(net_path), route_dicts, s.demand, vmax, seed)
            rows.append({
                "scenario": s.name, "copy": copy, "network": s.network,
                "role": "train" if copy < s.train_copies else s.role, "policy_scenario": s.policy_scenario,
                "arrival": s.demand.arrival, "noise_sigma_s": s.demand.noise_sigma_s, "duration_s": s.demand.duration_s,
                "demand_seed": seed, "max_speed_mps": vmax, **info,
            })
    return pl.DataFrame(rows).select(
        "scenario", "copy", "network", "role", "policy_scenario", "arrival", "noise_sigma_s", "duration_s", "demand_seed",
        "n_vehicles", "n_cars", "n_buses", "n_trucks", "last_depart_s", "max_speed_mps", "net_path", "routes_path", "folder",
    )


def files_of(row: dict) -> ScenarioFiles:
    return ScenarioFiles(row["net_path"], row["routes_path"], row["folder"], row["last_depart_s"], row["max_speed_mps"])


def route_agents(routes: pl.DataFrame, copies: pl.DataFrame) -> list[str]:
    """'route:class' of every route of the copies' network and every vehicle class they carry (urban_scenarios rows of
    one network): a cars-only scenario has no heavy route agents, which would never see a vehicle."""
    classes = [c for c, n in (("car", copies["n_cars"].sum()), ("heavy", copies["n_buses"].sum() + copies["n_trucks"].sum())) if n]
    return [f"{r}:{c}" for r in routes.filter(pl.col("network") == copies["network"][0])["route_id"] for c in classes]


# --- thesis tables ---------------------------------------------------------------------------------

TABLE_METHODS = {
    "3.2": ("ch3_dqn_cnn", "krauss", "idm"),  # chapter 3's method
    "4.3": ("col_marl", "col_marl_shield", "i_marl", "idm"),
    "4.4": ("col_marl", "col_marl_shield", "idm"),
    "4.5": ("col_marl", "col_marl_shield", "idm"),
    "4.7-4.9": ("col_marl", "col_marl_shield", "idm"),
}


def thesis_table_of(scenario: str, policy_scenario: str) -> list[str]:
    """Which thesis tables a scenario's evaluation rows belong to: 4.4 holds the CR/MR/LR noise levels
    (in the demo MR and LR are driven by CR's policies, so they also count as knowledge reuse, 4.7-4.9)."""
    out = ["4.4"] if scenario in ("real_cr", "real_mr", "real_lr") else []
    if scenario != policy_scenario:
        return out + ["4.7-4.9"]
    out.append("3.2")
    if scenario.startswith("sc"):
        out.append("4.3")
    elif scenario.startswith("real_ls"):
        out.append("4.5")
    return out


def thesis_tables(results: pl.DataFrame, scenarios_df: pl.DataFrame) -> pl.DataFrame:
    """Mean and std over copies x seeds per thesis table, scenario and method. Travel time and speed are
    averaged over successful runs when there are any (the thesis reports i-MARL on resolved cases only)."""
    policy_of = dict(scenarios_df.select("scenario", "policy_scenario").unique().iter_rows())
    rows = []
    for (scenario, method), g in results.group_by("scenario", "method", maintain_order=True):
        ok = g.filter(pl.col("success")) if g["success"].any() else g
        for table in thesis_table_of(scenario, policy_of[scenario]):
            if method not in TABLE_METHODS[table]:
                continue
            rows.append({
                "thesis_table": table, "scenario": scenario, "method": method, "runs": g.height,
                "travel_time_mean_s": ok["avg_travel_time_s"].mean(), "travel_time_std_s": ok["avg_travel_time_s"].std(),
                "speed_mean_mps": ok["avg_speed_mps"].mean(), "speed_std_mps": ok["avg_speed_mps"].std(),
                "fuel_mean_mlps": ok["avg_fuel_mlps"].mean(), "fuel_std_mlps": ok["avg_fuel_mlps"].std(),
                "collisions_mean": float(g["collisions"].mean()), "collisions_std": g["collisions"].cast(pl.Float64).std(),
                "teleports_mean": float(g["teleports"].mean()), "success_rate": float(g["success"].mean()),
            })
    return pl.DataFrame(rows, schema_overrides={"runs": pl.Int64}).sort("thesis_table", "scenario", "method")


def thesis_markdown(tables: pl.DataFrame) -> str:
    """Each thesis table as markdown: one row per scenario, one column group per method, mean ± std."""

    def pm(m, s):
        return "—" if m is None or np.isnan(m) else f"{m:.1f} ± {0.0 if s is None or np.isnan(s) else s:.1f}"

    parts = []
    for (table,), g in tables.group_by("thesis_table", maintain_order=True):
        methods = [m for m in TABLE_METHODS[table] if m in set(g["method"])]
        head = ["scenario"] + [f"{q} {m}" for q in ("travel time s", "speed m/s", "fuel ml/s", "collisions", "success") for m in methods]
        lines = [f"**Table {table}**", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for (scenario,), h in g.group_by("scenario", maintain_order=True):
            by = {r["method"]: r for r in h.iter_rows(named=True)}
            cells = [scenario]
            for key in (("travel_time_mean_s", "travel_time_std_s"), ("speed_mean_mps", "speed_std_mps"), ("fuel_mean_mlps", "fuel_std_mlps"), ("collisions_mean", "collisions_std")):
                cells += [pm(by[m][key[0]], by[m][key[1]]) if m in by else "" for m in methods]
            cells += [f"{100 * by[m]['success_rate']:.0f}%" if m in by else "" for m in methods]
            lines.append("| " + " | ".join(cells) + " |")
        parts.append("\n".join(lines))
    return "\n\n".join(parts)


# --- paired comparisons over training seeds ---------------------------------------------------------

# (method, reference): Table 4.3's question (does the collision term matter: i-MARL against col-MARL) and what the
# safety layer changes on the same policies
COMPARISONS = (("i_marl", "col_marl"), ("col_marl_shield", "col_marl"))
COMPARED_METRICS = ("collisions", "teleports", "success", "avg_travel_time_s")


def comparisons(results: pl.DataFrame) -> pl.DataFrame:
    """COMPARISONS on every scenario where both methods were evaluated, paired over training seeds on the held-out copies
    both ran (models.stats.paired_comparisons). One seed gives p = 1: a difference, not evidence."""
    return paired_comparisons(results, "scenario", COMPARISONS, COMPARED_METRICS, replicate="copy")


# --- evaluation runs (in worker processes) ---------------------------------------------------------


@dataclass
class SumoJob:
    files: ScenarioFiles
    model: str
    seed: int
    n_vehicles: int
    record: bool = False


def run_job(job):
    """Worker entry point: an RL episode (EpisodeJob) or a SUMO baseline run (SumoJob) -> (metrics, frames, vehicles that
    collided, vehicles SUMO teleported)."""
    from models.urban.col_marl import run_episode
    from models.urban.sim import run_sumo_model

    if isinstance(job, SumoJob):
        return run_sumo_model(job.files, job.n_vehicles, job.model, job.seed, job.record)
    result = run_episode(job)
    return result.metrics, result.frames, result.collided, result.teleported


def held_out(scenarios_df: pl.DataFrame, scenarios: list[str] | None = None, copies: int | None = None) -> pl.DataFrame:
    """The copies to evaluate: every non-training copy, or only those of `scenarios`, and at most the first `copies` of
    each (the paper profile has 220 held-out copies, up to 50,000 vehicles each: hours even for one seed)."""
    rows = scenarios_df.filter(pl.col("role") != "train")
    if scenarios is not None:
        known = rows["scenario"].unique(maintain_order=True).to_list()
        if unknown := sorted(set(scenarios) - set(known)):
            raise UrbanInputError(f"evaluation scenarios {unknown} have no held-out copies; expected some of {', '.join(known)}")
        rows = rows.filter(pl.col("scenario").is_in(scenarios))
    if copies is not None:
        if copies < 1:
            raise UrbanInputError(f"evaluation copies must be >= 1, got {copies}")
        rows = rows.filter(pl.col("copy").rank("ordinal").over("scenario") <= copies)
    return rows


def evaluation_jobs(scenarios_df: pl.DataFrame, policies: dict, methods: list[str], record: bool = False,
                    scenarios: list[str] | None = None, copies: int | None = None):
    """(row keys, job) for every held-out copy (`held_out`: scenarios, copies) x method x seed. policies: (scenario,
    method) -> {seed: (agents, params, leader_guard)}; a METHODS_SHIELDED method drives its trained method's policies
    with the safety layer on. record: only the first held-out copy of each scenario evaluated with its own policies,
    one policy seed per method, recorded (for trajectories). One line when nothing is left to run."""
    from models.urban.col_marl import EpisodeJob

    if unknown := sorted(set(methods) - set(EVALUATION_METHODS)):
        raise UrbanInputError(f"evaluation methods {unknown}: expected some of {', '.join(EVALUATION_METHODS)}")
    out = []
    rows = held_out(scenarios_df, scenarios, copies)
    if record:
        rows = rows.filter(pl.col("scenario") == pl.col("policy_scenario"))
        rows = rows.filter(pl.col("copy") == pl.col("copy").min().over("scenario"))
    for row in rows.iter_rows(named=True):
        files = files_of(row)
        for method in methods:
            if method in METHODS_SUMO:
                out.append(((row["scenario"], row["copy"], method, 0, row["n_vehicles"]),
                            SumoJob(files, METHODS_SUMO[method], 0, row["n_vehicles"], record)))
                continue
            trained = METHODS_SHIELDED.get(method, method)
            for seed, (agents, params, guard) in sorted(policies.get((row["policy_scenario"], trained), {}).items()):
                out.append(((row["scenario"], row["copy"], method, seed, row["n_vehicles"]),
                            EpisodeJob(files, METHODS_RL[trained], agents, params, epsilon=0.0, seed=EVAL_EPISODE_SEED + row["copy"],
                                       n_vehicles=row["n_vehicles"], record=record, leader_guard=guard, shield=method in METHODS_SHIELDED)))
                if record:
                    break  # one policy per method is enough for the trajectories
    if not out:  # e.g. only learned methods with no policies for the selected scenarios
        raise UrbanInputError(f"nothing to evaluate for methods {methods} on scenarios {scenarios or 'all'}: a learned method needs "
                              "its urban_training policies for the scenario" + ("; trajectories need a copy evaluated with its own policies" if record else ""))
    return out


def results_rows(keys: list, outputs: list) -> pl.DataFrame:
    return pl.DataFrame(
        [{"scenario": s, "copy": c, "method": m, "seed": seed, **out[0], "n_vehicles": n}
         for (s, c, m, seed, n), out in zip(keys, outputs)],
        schema_overrides={"copy": pl.Int64, "seed": pl.Int64, "collisions": pl.Int64, "teleports": pl.Int64, "arrived": pl.Int64, "n_vehicles": pl.Int64},
    ).select("scenario", "copy", "method", "seed", "avg_travel_time_s", "avg_speed_mps", "avg_fuel_mlps",
             "collisions", "teleports", "arrived", "n_vehicles", "success")


def trajectories_rows(keys: list, outputs: list) -> pl.DataFrame:
    """1 s snapshots of the recorded episodes -> urban_trajectories rows (one DataFrame per snapshot, no per-point loop)."""
    frames, failed = [], []
    for (scenario, _, method, _, _), (_, snaps, hit, jumped) in zip(keys, outputs):
        frames += [
            pl.DataFrame({"scenario": scenario, "method": method, "vehicle_id": pl.Series(s.ids, dtype=pl.String), "t": s.t,
                          "x": s.x, "y": s.y, "speed_mps": s.speed, "accel_mps2": s.accel})
            for s in snaps if s.ids
        ]
        failed += [{"scenario": scenario, "method": method, "vehicle_id": v, "collided": v in hit, "teleported": v in jumped}
                   for v in sorted(hit | jumped)]
    df = pl.concat(frames)
    hits = pl.DataFrame(failed, schema={"scenario": pl.String, "method": pl.String, "vehicle_id": pl.String, "collided": pl.Boolean,
                                        "teleported": pl.Boolean})
    parts = df["vehicle_id"].str.split_exact(".", 2).struct.rename_fields(["route", "cls", "n"]).struct.unnest()
    return (
        df.with_columns(route=parts["route"], agent=parts["route"] + ":" + parts["cls"])
        .join(hits, on=["scenario", "method", "vehicle_id"], how="left", maintain_order="left")
        .with_columns(pl.col("collided", "teleported").fill_null(False))
        .select("scenario", "method", "vehicle_id", "t", "x", "y", "speed_mps", "accel_mps2", "route", "agent", "collided", "teleported")
    )
