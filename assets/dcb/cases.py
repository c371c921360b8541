"""Evaluation cases (capacity scalings, like thesis Table 5.1), their hotspots, and the reference solutions."""

import time

import dagster as dg
import polars as pl
from pydantic import Field

from assets.profiles import default_profile, resolve
from models.dcb.experiment import build_problem, case_name, case_row, delay_rows, hotspots_before
from models.dcb.optimum import InfeasibleError, fcfs, solve_optimum
from models.dcb.readout import readout_only

# capacity scales of the evaluation cases, easiest first (the demo runs the easiest only)
PROFILE = {"demo": {"capacity_scales": [0.95]}, "paper": {"capacity_scales": [0.95, 0.9, 0.85, 0.8]}}


class CasesConfig(dg.Config):
    profile: str = Field(default_factory=default_profile, description="demo: case cap95 only; paper: cap95, cap90, cap85, cap80")
    capacity_scales: list[float] | None = Field(default=None, description="capacity scale per case (None: the profile's)")
    max_delay_min: int = Field(default=60, description="MaxDelay: the largest ground delay a learner may give [min]")


def case_scales(config: CasesConfig) -> list[float]:
    """The cases' capacity scales; one line for a config no case can use."""
    scales = resolve(config, PROFILE)["capacity_scales"]
    if not scales or min(scales) <= 0:
        raise ValueError(f"capacity_scales {scales}: expected one or more scales > 0")
    names = [case_name(s) for s in scales]
    if len(set(names)) != len(names):
        raise ValueError(f"capacity_scales {scales} give the cases {names}: a case is named by its scale in whole percent, so each needs its own")
    if config.max_delay_min < 1:
        raise ValueError(f"max_delay_min {config.max_delay_min}: expected a whole number of minutes >= 1")
    return scales


def problems(cases: pl.DataFrame, entries: pl.DataFrame, sectors: pl.DataFrame, flights: pl.DataFrame) -> dict:
    """case -> DCBProblem, rebuilt from the tables (deterministic)."""
    return {r["case"]: build_problem(entries, sectors, flights, r["capacity_scale"], r["max_delay_min"]) for r in cases.iter_rows(named=True)}


@dg.multi_asset(
    group_name="dcb",
    outs={"dcb_cases": dg.AssetOut(description="Evaluation cases described like Table 5.1."),
          "dcb_hotspots": dg.AssetOut(description="Hotspots of every case before any delay.")},
)
def dcb_cases(context: dg.AssetExecutionContext, config: CasesConfig, dcb_sector_entries: pl.DataFrame, dcb_sectors: pl.DataFrame,
              dcb_flights: pl.DataFrame):
    rows, hot = [], []
    for scale in case_scales(config):
        problem = build_problem(dcb_sector_entries, dcb_sectors, dcb_flights, scale, config.max_delay_min)
        rows.append(case_row(case_name(scale), scale, problem))
        hot.append(hotspots_before(case_name(scale), problem))
        context.log.info(f"case {rows[-1]}")
    cases = pl.DataFrame(rows)
    return (dg.Output(cases, metadata={"cases": dg.MetadataValue.json(rows)}),
            dg.Output(pl.concat(hot), metadata={"hotspots": dg.MetadataValue.json(dict(cases.select("case", "hotspots").iter_rows()))}))


class ReferenceConfig(dg.Config):
    time_limit_s: float = Field(default=300.0, description="HiGHS time limit per case [s]; a case not solved to optimality gets no optimum row")


@dg.asset(group_name="dcb", description="Exact minimum-total-delay solution (integer program, HiGHS), FCFS ground delays and the learners' read-out applied to zero delays (readout_only) per case.")
def dcb_reference(context: dg.AssetExecutionContext, config: ReferenceConfig, dcb_cases: pl.DataFrame, dcb_sector_entries: pl.DataFrame,
                  dcb_sectors: pl.DataFrame, dcb_flights: pl.DataFrame) -> dg.Output:
    frames, solve = [], {}
    for case, problem in problems(dcb_cases, dcb_sector_entries, dcb_sectors, dcb_flights).items():
        started = time.perf_counter()
        try:
            first_come = fcfs(problem)
            frames.append(delay_rows(case, "FCFS", 0, problem, first_come, time.perf_counter() - started))
        except InfeasibleError as e:  # a sector file's capacities far below the demand
            context.log.warning(f"{case}: no FCFS - {e}")
            first_come = None
        # the learners' read-out with no learning at all: what the policies must beat to have added anything
        started = time.perf_counter()
        no_policy = readout_only(problem)
        frames.append(delay_rows(case, "readout_only", 0, problem, no_policy, time.perf_counter() - started))
        solve[case] = {"fcfs_total_delay_min": None if first_come is None else int(first_come.sum()),
                       "readout_only_total_delay_min": int(no_policy.sum())}
        try:
            delay, solve_s = solve_optimum(problem, config.time_limit_s)
        except InfeasibleError as e:  # the case stays usable: learners still run, gaps are null
            context.log.warning(f"{case}: no optimum - {e}")
            solve[case]["optimum"] = str(e)
            continue
        frames.append(delay_rows(case, "optimum", 0, problem, delay, solve_s))
        solve[case].update(optimum_total_delay_min=int(delay.sum()), solve_s=round(solve_s, 2))
        context.log.info(f"{case}: {solve[case]}")
    return dg.Output(pl.concat(frames), metadata={"per_case": dg.MetadataValue.json(solve)})
