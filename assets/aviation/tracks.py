"""Constant-step tracks with weather and phases: flight_tracks -> tracks_20s -> flight_phases."""

import dagster as dg
import polars as pl
from pydantic import Field

from models.aviation.airports import airports_table
from models.aviation.phases import PhaseConfig, assign_phases, phase_table
from models.aviation.plots import altitude_profiles_by_phase
from models.aviation.resample import resample
from models.aviation.weather import ALIGNMENTS, sample_weather, share_outside_levels, weather_time_range
from warehouse.artifacts import save_plot

_P = PhaseConfig()


class TracksConfig(dg.Config):
    dt_s: float = Field(default=20.0, description="time step of the constant-step tracks [s]")
    weather_alignment: str = Field(
        default="time_of_day",
        description="how flight times meet weather times: 'exact' (real timestamps, must lie inside the weather's "
        "range) or 'time_of_day' (the point's UTC time of day on the weather's first day, clamped to its range; "
        "for sample weather from other dates)",
    )
    phase_method: str = Field(default=_P.method, description="'vertical' (thesis §7.4.1 rules) or 'regions'")
    climb_rate_mps: float = Field(default=_P.climb_rate_mps, description="climbing flag: ΔH/ΔT above this [m/s]")
    descent_drop_m: float = Field(default=_P.descent_drop_m, description="descent starts on a drop above this per step [m]")
    climb_end_fraction: float = Field(default=_P.climb_end_fraction, description="climb ends only after this share of the estimated duration")
    descent_start_fraction: float = Field(default=_P.descent_start_fraction, description="descent starts only after this share of the estimated duration")
    climb_radius_km: float = Field(default=_P.climb_radius_km, description="'regions': climb ends on leaving this circle around the origin [km]")
    descent_radius_km: float = Field(default=_P.descent_radius_km, description="'regions': descent starts on entering this circle around the destination [km]")


@dg.asset(group_name="aviation", description="Constant-step tracks with weather at every 4D point and the flight phase.")
def tracks_20s(
    context: dg.AssetExecutionContext, config: TracksConfig, flight_tracks: pl.DataFrame, flights: pl.DataFrame, weather: pl.DataFrame
):
    if config.weather_alignment not in ALIGNMENTS:
        raise ValueError(f"weather_alignment must be one of {ALIGNMENTS}, got '{config.weather_alignment}'")
    grid = resample(flight_tracks, config.dt_s)
    met = sample_weather(weather, grid["ts"], grid["lat"].to_numpy(), grid["lon"].to_numpy(), grid["alt_m"].to_numpy(), alignment=config.weather_alignment)
    grid = grid.with_columns(**{k: pl.Series(v) for k, v in met.items()})
    clamped = share_outside_levels(weather, grid["alt_m"].to_numpy())
    if clamped > 0.01:
        levels = weather["level_hpa"]
        context.log.warning(f"{clamped:.0%} of the points fly outside the weather's levels ({levels.min():g}-{levels.max():g} hPa) "
                            "and get the nearest level's temperature and wind")
    phase_cfg = PhaseConfig(
        method=config.phase_method,
        climb_rate_mps=config.climb_rate_mps,
        descent_drop_m=config.descent_drop_m,
        climb_end_fraction=config.climb_end_fraction,
        descent_start_fraction=config.descent_start_fraction,
        climb_radius_km=config.climb_radius_km,
        descent_radius_km=config.descent_radius_km,
    )
    tracks = assign_phases(grid, flights, phase_cfg, airports_table())
    context.log.info(f"{tracks.height:,} points at {config.dt_s:g} s for {tracks['flight_id'].n_unique()} flights")
    w0, w1 = weather_time_range(weather)
    path, md = save_plot("altitude_profiles_by_phase", altitude_profiles_by_phase(tracks))
    return dg.Output(
        tracks,
        metadata={
            "dt_s": config.dt_s,
            "weather_alignment": config.weather_alignment,
            "share_outside_weather_levels": round(clamped, 4),
            "weather_time_range": f"{w0} .. {w1}",
            "flights_time_range": f"{tracks['ts'].min()} .. {tracks['ts'].max()}",
            "phase_method": config.phase_method,
            "points_per_phase": dg.MetadataValue.json(dict(tracks["phase"].value_counts().rows())),
            "altitude_profiles": dg.MetadataValue.md(md),
            "altitude_profiles_png": dg.MetadataValue.path(str(path)),
        },
    )


@dg.asset(group_name="aviation", description="One row per flight and phase (climb, cruise, descent) with its time span.")
def flight_phases(tracks_20s: pl.DataFrame):
    phases = phase_table(tracks_20s)
    return dg.Output(phases, metadata={"flights_per_phase": dg.MetadataValue.json(dict(phases["phase"].value_counts().rows()))})
