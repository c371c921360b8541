"""Files that are not tables (plots, rerun recordings, model files), kept under TRAFFICLEARN_HOME."""

import base64
from pathlib import Path

from warehouse.storage import home, replace_atomically


def artifact_path(kind: str, name: str) -> Path:
    path = home() / kind / name
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def write_bytes_atomic(path: Path, data: bytes) -> Path:
    return replace_atomically(path, lambda tmp: Path(tmp).write_bytes(data))


def save_plot(name: str, png: bytes) -> tuple[Path, str]:
    """Write `plots/<name>.png` and return (path, markdown embedding it) for Dagster metadata."""
    path = write_bytes_atomic(artifact_path("plots", f"{name}.png"), png)
    return path, f"![{name}](data:image/png;base64,{base64.b64encode(png).decode()})"
