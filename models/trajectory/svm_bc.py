"""Behavioural cloning with an RBF-kernel SVM: the baseline of thesis chapter 6 (§6.5.2), beside AppLearn.

Every expert step s_t -> s_{t+1} is labelled with the discrete heading θ_k of the heading environment
(models.trajectory.heading_env, Eq 6.4) closest to its direction in the (Δlon, Δlat)-scaled frame:

    k*(t) = argmax_k cos(θ_k - atan2(Δlat_t / Δlat, Δlon_t / Δlon))

and an SVM with an RBF kernel learns state -> k* from the spatio-temporal (lon, lat, alt, elapsed time) and
meteorological (temperature, u-wind, v-wind) features of s_t, z-scored. The policy plays the predicted heading.
"""

from dataclasses import dataclass

import numpy as np
import polars as pl

from models.trajectory.heading_env import AltitudeNet, HeadingEnv, HeadingGeometry, expert_observations

# ------------------------------------------------------------------------------------------ hyperparameters
C = 1.0  # SVM soft-margin penalty (sklearn default, as the thesis gives none)
GAMMA = "scale"  # RBF width: 1 / (n_features · Var(x)) on the z-scored features
MAX_TRAIN_POINTS = 20_000  # the kernel SVM is quadratic in the points: subsample beyond this many


def expert_heading_labels(tracks: pl.DataFrame, geometry: HeadingGeometry) -> tuple[np.ndarray, np.ndarray]:
    """(observations of s_t, index of the heading closest to s_t -> s_{t+1}) for every expert step."""
    obs = expert_observations(tracks)
    flight = tracks.sort("flight_id", "ts")["flight_id"].to_numpy()
    has_next = flight[:-1] == flight[1:]
    d = np.diff(obs[:, :2], axis=0)[has_next]
    angle = np.arctan2(d[:, 1] / geometry.step_lat_deg, d[:, 0] / geometry.step_lon_deg)
    labels = np.cos(angle[:, None] - np.asarray(geometry.headings_rad)[None]).argmax(axis=1)
    return obs[:-1][has_next], labels


@dataclass
class SVMPolicy:
    """The fitted classifier with the environment it acts in."""

    geometry: HeadingGeometry
    altitude: AltitudeNet
    x_mean: np.ndarray
    x_std: np.ndarray
    svm: object  # sklearn.svm.SVC

    def policy(self, obs: np.ndarray) -> np.ndarray:
        return self.svm.predict((obs - self.x_mean) / self.x_std).astype(np.int64)

    def env(self, weather: pl.DataFrame) -> HeadingEnv:
        return HeadingEnv(self.geometry, self.altitude, weather)


def train_svm_bc(tracks: pl.DataFrame, geometry: HeadingGeometry, altitude: AltitudeNet, seed: int) -> SVMPolicy:
    """Fit the SVM on the expert flights in `tracks`; geometry and NN_altitude are shared with AppLearn."""
    from sklearn.svm import SVC

    x, y = expert_heading_labels(tracks, geometry)
    if len(x) > MAX_TRAIN_POINTS:
        keep = np.random.default_rng(seed).permutation(len(x))[:MAX_TRAIN_POINTS]
        x, y = x[keep], y[keep]
    mean, std = x.mean(axis=0), x.std(axis=0).clip(1e-6)
    if len(np.unique(y)) == 1:  # one heading only (e.g. a straight single expert): SVC needs two classes
        svm = _Constant(int(y[0]))
    else:
        svm = SVC(C=C, kernel="rbf", gamma=GAMMA, random_state=seed).fit((x - mean) / std, y)
    return SVMPolicy(geometry, altitude, mean, std, svm)


@dataclass
class _Constant:
    label: int

    def predict(self, x: np.ndarray) -> np.ndarray:
        return np.full(len(x), self.label)
