"""A matplotlib figure as PNG bytes (object API on an Agg canvas: no pyplot state, safe in worker processes)."""

import io

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure


def png_bytes(fig: Figure) -> bytes:
    """Laid out tight, at the figure's own dpi."""
    fig.tight_layout()
    buf = io.BytesIO()
    FigureCanvasAgg(fig).print_png(buf)
    return buf.getvalue()
