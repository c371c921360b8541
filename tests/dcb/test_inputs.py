"""Bad demand or sector input: one clear line, nothing silently dropped (every row/line accounted for)."""

import json

import numpy as np
import polars as pl
import pytest

from models.dcb.airspace import GeoJSONSectorisation, SectorFileError, sector_entries
from models.dcb.demand import DemandError, read_so6
from models.dcb.experiment import airspace_tables, load_demand, sectorisation

GOOD = [
    "LSGG_LSZH LSGG LSZH A320 100000 101500 300 360 0 SWR100 180801 180801 2784.0 372.0 2784.0 480.0 F1 1 50.0 0",
    "LSZH_EDDM LSZH EDDM B77W 101500 103000 360 360 0 SWR100 180801 180801 2784.0 480.0 2820.0 540.0 F1 2 40.0 0",
    "LFLL_LIMC LFLL LIMC E190 120000 121000 320 340 0 AFR200 180801 180801 2760.0 400.0 2760.0 500.0 F2 1 60.0 0",
]
BAD = {
    "wrong_field_count": "LSGG_LSZH LSGG LSZH A320 100000 101500 300",
    "bad_number": "LSGG_LSZH LSGG LSZH A320 100000 101500 3x0 360 0 SWR101 180801 180801 2784.0 372.0 2784.0 480.0 F3 1 50.0 0",
    "time_reversed": "LSGG_LSZH LSGG LSZH A320 101500 100000 300 360 0 SWR102 180801 180801 2784.0 372.0 2784.0 480.0 F4 1 50.0 0",
}
SECTORS = {"type": "FeatureCollection", "features": [
    {"type": "Feature", "properties": {"name": "WEST", "fl_lower": 285, "fl_upper": 400, "capacity_per_h": 1},
     "geometry": {"type": "Polygon", "coordinates": [[[6.0, 46.0], [8.0, 46.0], [8.0, 47.0], [6.0, 47.0], [6.0, 46.0]]]}},
    {"type": "Feature", "properties": {"name": "EAST", "fl_lower": 285, "fl_upper": 400},
     "geometry": {"type": "Polygon", "coordinates": [[[8.0, 46.0], [10.0, 46.0], [10.0, 47.0], [8.0, 47.0], [8.0, 46.0]]]}},
]}


def test_malformed_so6_lines_are_quarantined_and_counted(tmp_path):
    path = tmp_path / "day.so6"
    path.write_text("\n".join([GOOD[0], BAD["wrong_field_count"], GOOD[1], BAD["bad_number"], "", GOOD[2], BAD["time_reversed"]]) + "\n")
    segments, rejects = read_so6(path)
    assert segments.height == 3
    assert dict(zip(rejects["reason"], rejects["line_number"])) == {"wrong_field_count": 2, "bad_number": 4, "time_reversed": 7}
    points, flights, rej, summary = load_demand(path)
    counts = {(o, r): n for _, o, r, n in summary.iter_rows()}
    assert counts[("read", "")] == 6 == counts[("kept", "")] + rej.height  # the blank line is not a record
    assert rej["detail"].to_list() == [BAD["wrong_field_count"], BAD["bad_number"], BAD["time_reversed"]]
    assert dict(zip(flights["flight_id"], flights["aircraft_class"])) == {"F1": "narrowbody", "F2": "regional_jet"}
    # SO6 minutes of arc: 2784' = 46.4 N; the F1 segment at FL300-360 crosses from WEST into EAST at 8 E
    sectors_path = tmp_path / "sectors.geojson"
    sectors_path.write_text(json.dumps(SECTORS))
    entries = sector_entries(points, GeoJSONSectorisation(str(sectors_path)))
    assert entries.filter(pl.col("flight_id") == "F1")["sector"].to_list() == ["WEST", "EAST"]


def test_so6_times_must_be_hhmmss_and_tabs_separate_fields(tmp_path):
    hhmm = GOOD[2].replace("120000 121000", "1200 1210")  # HHMM: not 00:12:00
    lost_zero = GOOD[2].replace("120000 121000", "12000 121000")  # 01:20:00 without its leading zero: not 12:00:00
    tabs = GOOD[0].replace(" ", "\t")
    path = tmp_path / "day.so6"
    path.write_text("\n".join([hhmm, tabs, lost_zero]) + "\n")
    segments, rejects = read_so6(path)
    assert rejects.select("line_number", "reason").rows() == [(1, "bad_time_or_date"), (3, "bad_time_or_date")]
    assert segments["flight_id"].to_list() == ["F1"]


def test_so6_without_a_usable_line_is_one_clear_error(tmp_path):
    path = tmp_path / "bad.so6"
    path.write_text(BAD["wrong_field_count"] + "\n")
    with pytest.raises(DemandError, match=r"no usable SO6 line \(1 rejected") as e:
        load_demand(path)
    assert "\n" not in str(e.value)
    for empty in ("", "\n  \n"):  # an empty file, or blank lines only
        path.write_text(empty)
        with pytest.raises(DemandError, match="the SO6 file has no lines"):
            load_demand(path)
    with pytest.raises(DemandError, match="no such SO6 file"):
        load_demand(tmp_path / "missing.so6")
    with pytest.raises(DemandError, match="SO6 files are read uncompressed, as .so6"):
        load_demand(tmp_path / "day.so6.gz")
    path.write_text("\n".join(GOOD) + "\n")
    for step in (0, -30):
        with pytest.raises(DemandError, match=f"so6_step_s {step}: expected a positive step"):
            load_demand(path, so6_step_s=step)


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d["features"][0]["properties"].pop("fl_upper"), r"feature 0 lacks properties \['fl_upper'\]"),
    (lambda d: d["features"][1]["geometry"].update(type="Point"), r"feature 1 \(EAST\): geometry must be a Polygon"),
    (lambda d: d["features"][1]["properties"].update(name="WEST"), "sector names are not unique"),
    (lambda d: d["features"][0]["properties"].update(capacity_per_h=0), "capacity_per_h 0 must be a positive integer"),
    (lambda d: d.update(type="Feature"), "expected a GeoJSON FeatureCollection"),
])
def test_malformed_sector_file_is_one_clear_error(tmp_path, mutate, message):
    doc = json.loads(json.dumps(SECTORS))
    mutate(doc)
    path = tmp_path / "sectors.geojson"
    path.write_text(json.dumps(doc))
    with pytest.raises(SectorFileError, match=message) as e:
        GeoJSONSectorisation(str(path)).sectors()
    assert "\n" not in str(e.value)


def test_sector_file_that_is_not_json(tmp_path):
    path = tmp_path / "sectors.geojson"
    path.write_text("{not json")
    with pytest.raises(SectorFileError, match="not valid JSON"):
        GeoJSONSectorisation(str(path)).sectors()


def test_grid_sectorisation_locates_points_and_rejects_bad_grids():
    from models.dcb.airspace import GridSectorisation

    g = GridSectorisation()  # 2 x 4 cells of 1 deg x 1.15 deg from (45.8 N, 5.9 E), bands 285/355/375/480
    names = g.sectors()["sector"].to_list()
    idx = g.locate(np.array([45.9, 47.7, 46.9, 46.0, 46.0]), np.array([6.0, 10.4, 7.1, 6.0, 6.0]), np.array([300.0, 479.0, 360.0, 200.0, 380.0]))
    assert [names[i] if i >= 0 else None for i in idx] == ["R0C0_FL285-355", "R1C3_FL375-480", "R1C1_FL355-375", None, "R0C0_FL375-480"]
    with pytest.raises(SectorFileError, match="fl_edges"):
        GridSectorisation(fl_edges=(300.0, 300.0))
    with pytest.raises(SectorFileError, match=r"box \[45.8, 47.8, 5.9\] must be \[lat_min, lat_max, lon_min, lon_max\]"):
        sectorisation(None, 1.0, 1.0, [285.0, 480.0], [45.8, 47.8, 5.9])


def test_sector_file_no_flight_enters_is_one_clear_error(tmp_path):
    # the same sectors written [lat, lon] instead of GeoJSON's [lon, lat]: they lie in the Indian Ocean
    doc = json.loads(json.dumps(SECTORS))
    for f in doc["features"]:
        f["geometry"]["coordinates"] = [[[lat, lon] for lon, lat in f["geometry"]["coordinates"][0]]]
    sectors_path = tmp_path / "sectors.geojson"
    sectors_path.write_text(json.dumps(doc))
    so6 = tmp_path / "day.so6"
    so6.write_text("\n".join(GOOD) + "\n")
    points, flights, _, _ = load_demand(so6)
    with pytest.raises(SectorFileError, match=r"none of the 2 flights enters any of its 2 sectors: the flights lie at lat 46\.\.47, .*GeoJSON positions are \[lon, lat\]") as e:
        airspace_tables(points, flights, GeoJSONSectorisation(str(sectors_path)))
    assert "\n" not in str(e.value)


def test_so6_in_degrees_is_told_by_where_the_flights_lie(tmp_path):
    # the docs' most likely slip: SO6 positions in degrees instead of decimal minutes of arc (46.4 N = 2784.0),
    # which puts the flights near (0.8 N, 0.1 E); the line must say where they are, not blame a sector file
    def in_degrees(line):
        f = line.split()
        f[12:16] = [str(float(v) / 60) for v in f[12:16]]
        return " ".join(f)
    so6 = tmp_path / "day.so6"
    so6.write_text("\n".join(in_degrees(ln) for ln in GOOD) + "\n")
    points, flights, _, _ = load_demand(so6)
    with pytest.raises(SectorFileError, match=r"the grid sectorisation: none of the 2 flights enters any of its 24 sectors: "
                       r"the flights lie at lat 0\.77\.\.0\.78, lon 0\.1\.\.0\.15, FL 300\.\.360; the sectors at lat 45\.8\.\.47\.8, "
                       r"lon 5\.9\.\.10\.5, FL 285\.\.480 \(SO6 positions are decimal minutes of arc") as e:
        airspace_tables(points, flights, sectorisation(None, 1.0, 1.15, [285.0, 355.0, 375.0, 480.0], None))
    assert "\n" not in str(e.value)
