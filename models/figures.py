"""A matplotlib figure as PNG bytes (object API on an Agg canvas: no pyplot state, safe in worker processes)."""

import io

import polars as pl
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure


def png_bytes(fig: Figure) -> bytes:
    """Laid out tight, at the figure's own dpi."""
    fig.tight_layout()
    buf = io.BytesIO()
    FigureCanvasAgg(fig).print_png(buf)
    return buf.getvalue()


def over_seeds(frame: pl.DataFrame, keys: list[str], columns: tuple[str, ...]) -> pl.DataFrame:
    """Per `keys`, each column's mean over the seeds and their range: <column>_mean, _min, _max (for `band`)."""
    return frame.group_by(*keys, maintain_order=True).agg(
        *(f(c).alias(f"{c}_{f.__name__}") for c in columns for f in (pl.mean, pl.min, pl.max)))


def band(ax, x: pl.Series, curves: pl.DataFrame, column: str, color: str, label: str) -> None:
    """One learner's curve: the mean over seeds as a line, the seeds' range shaded."""
    ax.plot(x, curves[f"{column}_mean"], color=color, lw=1.2, label=label)
    ax.fill_between(x, curves[f"{column}_min"], curves[f"{column}_max"], color=color, alpha=0.15, lw=0)
