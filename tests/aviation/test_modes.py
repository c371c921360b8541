"""Route modes (thesis §7.4.1): normalised DTW, Ward + silhouette, real-data separation, plots, rerun file."""

from pathlib import Path

import numpy as np
import polars as pl
import pytest
from sklearn.metrics import adjusted_rand_score

from models.aviation.airports import flights_table
from models.aviation.ingest import ingest
from models.aviation.phases import assign_phases
from models.aviation.modes import (
    MODES_SCHEMA,
    cluster_series,
    cut,
    date_separation,
    minmax_scale,
    mode_purity,
    normalised_dtw_matrix,
    trajectory_modes,
)
from models.aviation.plots import (
    altitude_profiles_by_phase,
    dendrogram,
    png_markdown,
    silhouette_curve,
    tracks_map_by_mode,
)
from models.aviation.recording import read_recording_summary, write_modes_recording
from models.aviation.resample import resample
from tests.conftest import OPENSKY

CLOSURE = pl.Series(["2022-02-27"]).str.to_datetime(time_zone="UTC")[0]


def pipeline_tracks(path: Path = OPENSKY) -> tuple[pl.DataFrame, pl.DataFrame]:
    """The real pipeline up to phases: ingest -> airports -> 20 s tracks -> phases."""
    tracks, _, _ = ingest(path)
    flights = flights_table(tracks)
    return assign_phases(resample(tracks), flights), flights


@pytest.fixture(scope="module")
def real():
    tracks, flights = pipeline_tracks()
    modes, clusterings = trajectory_modes(tracks, flights)
    return tracks, flights, modes, clusterings


def _dtw_reference(a: np.ndarray, b: np.ndarray) -> float:
    """Textbook DTW (sqrt of the summed squared Euclidean distances along the best path)."""
    c = ((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)
    d = np.full((len(a) + 1, len(b) + 1), np.inf)
    d[0, 0] = 0.0
    for i in range(1, len(a) + 1):
        for j in range(1, len(b) + 1):
            d[i, j] = c[i - 1, j - 1] + min(d[i - 1, j], d[i, j - 1], d[i - 1, j - 1])
    return float(np.sqrt(d[-1, -1]))


# --------------------------------------------------------------------------------------------- DTW


def test_normalised_dtw_matrix_is_symmetric_zero_diagonal_and_exact():
    rng = np.random.default_rng(0)
    series = [np.cumsum(rng.normal(size=(n, 3)), axis=0) * 0.05 for n in (20, 25, 31, 20, 40, 17)]
    series.append(series[2].copy())  # identical to series 2
    d = normalised_dtw_matrix(series)
    assert d.shape == (7, 7)
    np.testing.assert_allclose(d, d.T)
    np.testing.assert_array_equal(np.diag(d), 0.0)
    assert d[2, 6] == 0.0
    assert np.isfinite(d).all() and (d[~np.eye(7, dtype=bool) & (d != d[2, 6])] > 0).all()
    # Eq 7.4 with exact DTW; (2, 5) is a pair that dtaidistance 2.5.1's pruning wrongly returns as inf
    for i, j in [(0, 1), (1, 4), (3, 0), (5, 4), (2, 5)]:
        expected = _dtw_reference(series[i], series[j]) / np.sqrt(3 * max(len(series[i]), len(series[j])))
        assert d[i, j] == pytest.approx(expected, rel=1e-9)


def test_minmax_scale_puts_each_variable_in_unit_range():
    x = np.array([[20.0, 55.0, 0.0], [37.0, 60.0, 11000.0], [30.0, 57.5, 5500.0], [30.0, 57.5, 5500.0]])
    s = minmax_scale(x)
    np.testing.assert_allclose(s.min(axis=0), 0.0)
    np.testing.assert_allclose(s.max(axis=0), 1.0)
    assert np.isfinite(minmax_scale(np.ones((3, 3)))).all()


# --------------------------------------------------------------------------------------------- clustering


def _two_groups(n_a: int, n_b: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for offset, n in ((0.0, n_a), (0.6, n_b)):
        for _ in range(n):
            t = np.linspace(0, 1, int(rng.integers(30, 45)))
            out.append(np.column_stack([t, offset + 0.1 * np.sin(3 * t), t**2]) + rng.normal(0, 0.01, (len(t), 3)))
    return out


def test_cluster_series_finds_groups_numbered_by_size():
    c = cluster_series(_two_groups(4, 7), max_modes=5)
    assert c.n_modes == 2 and c.silhouette is not None and c.silhouette > 0.5
    np.testing.assert_array_equal(c.labels, [1] * 4 + [0] * 7)  # 0 = largest
    assert set(c.silhouette_curve) == {2, 3, 4, 5}
    assert c.silhouette == max(c.silhouette_curve.values())
    assert c.linkage.shape == (10, 4)
    np.testing.assert_array_equal(cut(c, 2), c.labels)
    assert len(np.unique(cut(c, 4))) == 4
    np.testing.assert_array_equal(cut(c, 1), 0)


def test_cluster_series_small_sets_get_one_mode():
    for n in (0, 1, 2):
        c = cluster_series(_two_groups(n, 0))
        assert c.n_modes == (1 if n else 0) and c.silhouette is None and c.silhouette_curve == {}
        assert len(c.labels) == n and (c.labels == 0).all()


def test_mode_purity():
    truth = np.array([0, 0, 0, 1, 1, 1])
    assert mode_purity(np.array([0, 0, 0, 1, 1, 1]), truth) == 1.0
    assert mode_purity(np.array([0, 0, 1, 1, 1, 1]), truth) == pytest.approx(0.75)
    assert mode_purity(np.zeros(6, dtype=int), truth) == 0.5


# --------------------------------------------------------------------------------------------- real data


def test_whole_trajectory_modes_separate_the_airspace_closure(real):
    """UUEE->UMKK flights detour north over the Gulf of Finland from 2022-02-27: modes must see it."""
    tracks, flights, modes, clusterings = real
    c = clusterings[("UUEE-UMKK", "all")]
    assert len(c.flight_ids) == 57
    truth = (
        pl.DataFrame({"flight_id": list(c.flight_ids)})
        .join(flights, on="flight_id", how="left", maintain_order="left")
        .select(pl.col("first_ts") >= CLOSURE)
        .to_series()
        .to_numpy()
    )
    assert 0 < truth.sum() < len(truth)
    assert mode_purity(c.labels, truth) >= 0.95
    assert adjusted_rand_score(truth, cut(c, 2)) >= 0.9
    sep = date_separation(c, flights, CLOSURE)
    assert sep["n_flights"] == 57 and sep["purity"] >= 0.95 and sep["ari_at_2"] >= 0.9


def test_trajectory_modes_table(real):
    tracks, flights, modes, clusterings = real
    assert modes.schema == pl.Schema(MODES_SCHEMA)
    assert modes.columns == ["flight_id", "route", "phase", "mode", "n_modes", "silhouette"]
    every = modes.filter(pl.col("phase") == "all")
    assert every.height == flights.height and every["flight_id"].n_unique() == flights.height
    assert set(modes["phase"].unique()) == {"all", "climb", "cruise", "descent"}
    assert modes.select(pl.col("flight_id", "phase")).is_duplicated().sum() == 0
    # modes are 0..n_modes-1, mode 0 the largest, per route and phase
    per = modes.group_by("route", "phase", "mode").agg(pl.len(), pl.col("n_modes").first())
    for (route, phase), c in clusterings.items():
        g = per.filter(route=route, phase=phase).sort("mode")
        assert g["mode"].to_list() == list(range(c.n_modes))
        assert g["len"].to_list() == sorted(g["len"].to_list(), reverse=True)
    joined = modes.join(flights, on="flight_id")
    assert (joined["route"] == joined["route_right"]).all()


def test_small_routes_and_missing_phases(real):
    tracks, flights, _, _ = real
    two = flights.filter(pl.col("route") == "ULLI-UMKK").head(2)["flight_id"]
    first = flights["flight_id"][0]
    sub = tracks.filter(pl.col("flight_id").is_in(two.to_list()) | (pl.col("flight_id") == first)).filter(
        ~((pl.col("flight_id") == first) & (pl.col("phase") == "climb"))
    )
    modes, clusterings = trajectory_modes(sub, flights, min_flights=3)
    small = modes.filter(pl.col("route") == "ULLI-UMKK")
    assert (small["mode"] == 0).all() and (small["n_modes"] == 1).all() and small["silhouette"].is_null().all()
    assert modes.filter(pl.col("flight_id") == first)["phase"].sort().to_list() == ["all", "cruise", "descent"]
    assert clusterings[("ULLI-UMKK", "all")].linkage is None


# --------------------------------------------------------------------------------------------- outputs


def test_plots_are_png(real):
    tracks, flights, modes, clusterings = real
    pngs = [
        altitude_profiles_by_phase(tracks),
        tracks_map_by_mode(tracks, modes, phase="all"),
        tracks_map_by_mode(tracks, modes, phase="cruise"),
        silhouette_curve(clusterings),
        dendrogram(clusterings[("UUEE-UMKK", "all")], "UUEE-UMKK all"),
        dendrogram(cluster_series(_two_groups(1, 0)), "one flight"),
    ]
    for png in pngs:
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5_000
    md = png_markdown(pngs[0], "profiles")
    assert md.startswith("![profiles](data:image/png;base64,iVBORw0KGgo") and md.endswith(")")


def test_rerun_recording_is_written_atomically_and_rereadable(real, tmp_path):
    tracks, flights, modes, _ = real
    path = write_modes_recording(tracks, modes, tmp_path / "rec" / "modes.rrd")
    assert path == tmp_path / "rec" / "modes.rrd" and path.stat().st_size > 10_000
    assert [p.name for p in path.parent.iterdir()] == ["modes.rrd"]  # no temp file left behind
    summary = read_recording_summary(path)
    some = modes.filter(pl.col("phase") == "all").row(0, named=True)
    entity = f"/tracks/{some['route']}/mode_{some['mode']}/{some['flight_id']}"
    assert entity in summary["entities"] and f"{entity}/aircraft" in summary["entities"]
    n_flights = modes.filter(pl.col("phase") == "all").height
    assert sum(e.startswith("/tracks/") and e.endswith("/aircraft") for e in summary["entities"]) == n_flights


def test_one_minute_dtw_resolution_finds_the_same_modes(real):
    """The default stride (DTW on 1-min points) must not change the modes found on every 20 s point."""
    tracks, flights, modes, _ = real
    on_route = flights.filter(pl.col("route") == "UUEE-UMKK")
    full, _ = trajectory_modes(tracks, on_route, stride=1)
    both = full.join(modes, on=["flight_id", "phase"], suffix="_stride3")
    for phase in ("all", "cruise"):
        d = both.filter(pl.col("phase") == phase)
        assert adjusted_rand_score(d["mode"], d["mode_stride3"]) == 1.0
