"""The thesis's result tables (7.2-7.9) and error-growth figures (7.11-7.13) for our data, as markdown and PNG."""

import numpy as np
import polars as pl

from models.markdown import markdown_table

PHASE_COLUMNS = ("climb", "cruise", "descent", "total")
# EUROCONTROL growth-rate requirements quoted in §7.5.4 (nm per minute of look-ahead)
REQUIRED_GROWTH_NM_PER_MIN = {"climb": 0.2, "cruise": 0.1, "descent": 0.2}


def _cell(mean: float, std: float, metric: str) -> str:
    if metric in ("success_rate", "mode_accuracy"):
        return f"{100 * mean:.0f} ± {100 * std:.0f} %"
    return f"{mean:.2f} ± {std:.2f}"


def metric_table(metrics: pl.DataFrame, names: list[str], schemes: tuple[str, ...] = ("MMIL", "SMIL", "single")) -> str:
    """Rows (metric, method, scheme), columns climb/cruise/descent/total; cells mean ± std over seeds."""
    df = metrics.filter(pl.col("metric").is_in(names) & pl.col("scheme").is_in(schemes))
    if df.is_empty():
        return "_no rows_\n"
    df = df.with_columns(pl.struct("mean", "std", "metric").map_elements(lambda r: _cell(r["mean"], r["std"], r["metric"]), return_dtype=pl.String).alias("cell"))
    wide = df.pivot(on="phase", index=["metric", "method", "scheme"], values="cell")
    cols = [c for c in PHASE_COLUMNS if c in wide.columns]
    order = {n: i for i, n in enumerate(names)}
    wide = wide.with_columns(pl.col("metric").replace_strict(order, return_dtype=pl.Int64).alias("_o")).sort("_o", "method", "scheme").drop("_o")
    return markdown_table(wide.select("metric", "method", "scheme", *cols))


def posterior_tables(posteriors: pl.DataFrame) -> dict[str, str]:
    """Tables 7.6-7.8: per phase, rows (true mode, method), columns the mode whose mean probability is shown."""
    out = {}
    for phase in ("climb", "cruise", "descent", "all"):
        df = posteriors.filter(pl.col("phase") == phase)
        if df.is_empty():
            continue
        wide = df.pivot(on="predicted_mode", index=["true_mode", "method"], values="mean_probability").sort("true_mode", "method")
        out[phase] = markdown_table(wide.fill_null(0.0))
    return out


def growth_rates(growth: pl.DataFrame) -> pl.DataFrame:
    """Least-squares slope (nm/min) of each error against look-ahead minutes, with the EUROCONTROL requirement.

    Each minute is weighted by its number of roll-outs `n` (the pooled fit over every roll-out's minutes): the
    phases differ in length, so the last minutes hold a few long flights only, and with equal weights their
    errors (often a prediction that has already ended, held at its last point) set the slope."""
    rows = []
    for (method, scheme, phase), g in growth.group_by("method", "scheme", "phase", maintain_order=True):
        m = g["lookahead_min"].to_numpy().astype(float)
        if len(m) < 2:
            continue
        w = np.sqrt(g["n"].to_numpy().astype(float))  # polyfit squares the weights
        slope = {k: float(np.polyfit(m, g[k].to_numpy(), 1, w=w)[0]) for k in ("rmse_3d_nm", "ate_nm", "cte_nm")}
        rows.append({"method": method, "scheme": scheme, "phase": phase, **{f"{k}_per_min": v for k, v in slope.items()},
                     "required_nm_per_min": REQUIRED_GROWTH_NM_PER_MIN[phase]})
    return pl.DataFrame(rows).sort("phase", "method", "scheme")


def growth_figure(growth: pl.DataFrame, phase: str) -> bytes:
    """Figs 7.11-7.13: RMSE 3D, ATE and CTE (nm) per minute of look-ahead for every method, with the requirement line."""
    from matplotlib.figure import Figure

    from models.figures import png_bytes

    fig = Figure(figsize=(13, 3.8), dpi=90)
    axes = fig.subplots(1, 3)
    df = growth.filter(pl.col("phase") == phase)
    for (method, scheme), g in df.group_by("method", "scheme", maintain_order=True):
        ls = "-" if scheme == "MMIL" else ("--" if scheme == "SMIL" else ":")
        for ax, k in zip(axes, ("rmse_3d_nm", "ate_nm", "cte_nm")):
            ax.plot(g["lookahead_min"], g[k], ls, label=f"{method} {scheme}", lw=1.4)
    req = REQUIRED_GROWTH_NM_PER_MIN[phase]
    for ax, title in zip(axes, ("RMSE 3D", "ATE", "CTE")):
        if not df.is_empty():
            m = np.arange(1, int(df["lookahead_min"].max()) + 1)
            ax.plot(m, req * m, color="k", lw=0.8, alpha=0.6, label=f"{req} nm/min")
        ax.set_title(f"{title} — {phase}")
        ax.set_xlabel("look-ahead (min)")
        ax.set_ylabel("error (nm)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    return png_bytes(fig)


def thesis_tables(metrics: pl.DataFrame, posteriors: pl.DataFrame) -> dict[str, str]:
    rmse = ["rmse_lon_nm", "rmse_lat_nm", "rmse_alt_nm", "rmse_3d_nm"]
    track = ["ate_nm", "cte_nm", "vertical_ft", "eta_s"]
    tables = {
        "table_7_2": "RMSE (nm) of predicted trajectories, every method (MMIL phases are composed segments)\n\n" + metric_table(metrics, rmse),
        "table_7_3": "ATE, CTE (nm), vertical (ft) and ETA error (s)\n\n" + metric_table(metrics, track),
        "table_7_4": "RMSE of SMIL (and single-scheme methods) applied to phases\n\n" + metric_table(metrics, rmse, ("SMIL", "single")),
        "table_7_5": "ATE, CTE, V of SMIL applied to phases\n\n" + metric_table(metrics, track[:3], ("SMIL", "single")),
        "table_7_9": "Success rate (goal region reached) and mode accuracy\n\n" + metric_table(metrics, ["success_rate", "mode_accuracy"]),
    }
    for phase, md in posterior_tables(posteriors).items():
        number = {"climb": "7_6", "cruise": "7_7", "descent": "7_8", "all": "7_8_smil"}[phase]
        tables[f"table_{number}"] = f"Mean selector/posterior probabilities, {phase} (rows: true mode; columns: mode)\n\n" + md
    return tables
