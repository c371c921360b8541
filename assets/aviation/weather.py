"""Weather: an ERA5 NetCDF or GFS GRIB2 file -> the tidy `weather` grid."""

from pathlib import Path

import dagster as dg
from pydantic import Field

from models.aviation.weather import read_weather, weather_time_range

REPO = Path(__file__).resolve().parents[2]
DEFAULT_WEATHER = REPO / "data" / "weather" / "gfs_2011_isobaric_t_u_v.grib2"


class WeatherConfig(dg.Config):
    source_path: str = Field(
        default=str(DEFAULT_WEATHER),
        description="ERA5 NetCDF (.nc) or GFS GRIB2 (.grib2) with temperature and u/v wind on pressure levels; "
        "default: the bundled real GFS forecast (2011, not the flights' dates: see tracks_20s.weather_alignment)",
    )


@dg.asset(group_name="aviation", description="Tidy weather grid: time x pressure level x lat x lon.")
def weather(context: dg.AssetExecutionContext, config: WeatherConfig):
    grid = read_weather(config.source_path)
    start, end = weather_time_range(grid)
    levels = sorted(grid["level_hpa"].unique().to_list())
    context.log.info(f"weather {config.source_path}: {grid.height:,} values, {len(levels)} levels, {start} .. {end}")
    return dg.Output(
        grid,
        metadata={
            "source": config.source_path,
            "time_range": f"{start} .. {end}",
            "levels_hpa": dg.MetadataValue.json(levels),
        },
    )
