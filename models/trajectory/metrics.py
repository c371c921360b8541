"""Trajectory prediction errors (thesis §6.5.2, §7.5.3): DTW-matched RMSE, track errors, ETA, error growth.

A trajectory is an (n, 3) array of (lon deg, lat deg, alt m). Errors are measured in a local flat frame
around the actual trajectory (east/north in nautical miles, altitude in metres converted to nm for the
3D error and to feet for the vertical error), after matching every actual point to predicted points by
dynamic time warping (dtaidistance's C path) — the thesis's protocol, which makes the spatial error
independent of small speed differences; the timing error is reported separately as ETA error.
"""

import numpy as np
from dtaidistance import dtw_ndim

from models.units import M_PER_FT, M_PER_NM, MEAN_EARTH_RADIUS_KM

NM_PER_DEG_LAT = 60.0  # 1 arc-minute of latitude = 1 nm

METRIC_NAMES = ("rmse_lon_nm", "rmse_lat_nm", "rmse_alt_nm", "rmse_3d_nm", "ate_nm", "cte_nm", "vertical_ft")


def to_local_nm(points: np.ndarray, lat0_deg: float, lon0_deg: float) -> np.ndarray:
    """(n, 3) lon/lat/alt_m -> (n, 3) east/north/up in nm, equirectangular around (lat0, lon0)."""
    east = (points[:, 0] - lon0_deg) * NM_PER_DEG_LAT * np.cos(np.radians(lat0_deg))
    north = (points[:, 1] - lat0_deg) * NM_PER_DEG_LAT
    return np.stack([east, north, points[:, 2] / M_PER_NM], axis=1)


def dtw_match(actual_nm: np.ndarray, predicted_nm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices (i_actual, j_predicted) of the DTW warping path between two (n, 3) local-nm trajectories."""
    path = dtw_ndim.warping_path(
        np.ascontiguousarray(actual_nm, dtype=np.float64),
        np.ascontiguousarray(predicted_nm, dtype=np.float64),
        use_c=True,
    )
    idx = np.asarray(path, dtype=np.int64)
    return idx[:, 0], idx[:, 1]


def _check(name: str, arr: np.ndarray) -> np.ndarray:
    arr = np.asarray(arr, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3 or len(arr) < 2:
        raise ValueError(f"{name}: expected an (n>=2, 3) array of lon deg, lat deg, alt m, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name}: contains NaN or infinite values")
    return arr


def _unit_heading(track_nm: np.ndarray) -> np.ndarray:
    heading = np.gradient(track_nm[:, :2], axis=0)
    norm = np.linalg.norm(heading, axis=1, keepdims=True)
    return np.where(norm > 1e-9, heading / np.maximum(norm, 1e-12), np.array([1.0, 0.0]))


def matched_errors(actual: np.ndarray, predicted: np.ndarray) -> dict[str, float]:
    """Errors of one predicted trajectory against the actual one, both (n, 3) arrays of (lon deg, lat deg, alt m).

    Returns rmse_lon_nm, rmse_lat_nm, rmse_alt_nm, rmse_3d_nm (RMSE over DTW-matched pairs), ate_nm and
    cte_nm (RMS along-/cross-track error: the horizontal error projected on the predicted track's direction
    at the matched predicted point and on its normal), vertical_ft (RMS altitude error in feet).
    """
    actual, predicted = _check("actual", actual), _check("predicted", predicted)
    lat0, lon0 = float(actual[:, 1].mean()), float(actual[:, 0].mean())
    a_nm, p_nm = to_local_nm(actual, lat0, lon0), to_local_nm(predicted, lat0, lon0)
    i, j = dtw_match(a_nm, p_nm)
    err = p_nm[j] - a_nm[i]  # (k, 3) east, north, up in nm

    # Unit track direction of the predicted trajectory at the matched point (§7.5.3: ATE/CTE are measured
    # along and across the predicted trajectory; central differences, horizontal).
    heading = _unit_heading(p_nm)[j]
    along = (err[:, :2] * heading).sum(axis=1)
    cross = err[:, 0] * -heading[:, 1] + err[:, 1] * heading[:, 0]

    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    return {
        "rmse_lon_nm": rms(err[:, 0]),
        "rmse_lat_nm": rms(err[:, 1]),
        "rmse_alt_nm": rms(err[:, 2]),
        "rmse_3d_nm": rms(np.linalg.norm(err, axis=1)),
        "ate_nm": rms(along),
        "cte_nm": rms(cross),
        "vertical_ft": rms(err[:, 2] * M_PER_NM / M_PER_FT),
    }


def error_growth(actual: np.ndarray, predicted: np.ndarray, dt_s: float, horizon_min: int) -> np.ndarray:
    """Error at each minute of look-ahead (time-aligned, not DTW): (horizon_min, 3) of 3D, along-, cross-track nm.

    Both trajectories start at the same time with step dt_s; minute m compares the points m minutes in.
    Beyond the end of either trajectory its last point is held (a finished prediction stays where it ended).
    Growth per minute of look-ahead = the slope of these errors over m.
    """
    actual, predicted = _check("actual", actual), _check("predicted", predicted)
    lat0, lon0 = float(actual[:, 1].mean()), float(actual[:, 0].mean())
    a_nm, p_nm = to_local_nm(actual, lat0, lon0), to_local_nm(predicted, lat0, lon0)
    steps = np.round(np.arange(1, horizon_min + 1) * 60.0 / dt_s).astype(np.int64)
    ia, ip = np.minimum(steps, len(a_nm) - 1), np.minimum(steps, len(p_nm) - 1)
    err = p_nm[ip] - a_nm[ia]
    heading = _unit_heading(p_nm)[ip]
    along = np.abs((err[:, :2] * heading).sum(axis=1))
    cross = np.abs(err[:, 0] * -heading[:, 1] + err[:, 1] * heading[:, 0])
    return np.stack([np.linalg.norm(err, axis=1), along, cross], axis=1)


def haversine_km(a_lon_lat: np.ndarray, b_lon_lat: np.ndarray) -> np.ndarray:
    """Great-circle distance in km between (..., 2) lon/lat arrays (degrees)."""
    a, b = np.radians(np.asarray(a_lon_lat, float)), np.radians(np.asarray(b_lon_lat, float))
    h = np.sin((b[..., 1] - a[..., 1]) / 2) ** 2 + np.cos(a[..., 1]) * np.cos(b[..., 1]) * np.sin((b[..., 0] - a[..., 0]) / 2) ** 2
    return 2 * MEAN_EARTH_RADIUS_KM * np.arcsin(np.sqrt(np.clip(h, 0.0, 1.0)))
