"""Where the Dagster instance lives when a command is run without the Makefile (which sets DAGSTER_HOME)."""

import os
import shutil
from pathlib import Path

from warehouse.storage import home, replace_atomically

TEMPLATE = Path(__file__).resolve().parent.parent / "dagster.yaml"


def dagster_home() -> Path:
    """$DAGSTER_HOME if set; else $TRAFFICLEARN_HOME/dagster, as `make` sets it, with the checkout's dagster.yaml
    copied in when it has none. Exported, so that Dagster and its child processes use it too."""
    if os.environ.get("DAGSTER_HOME"):
        path = Path(os.environ["DAGSTER_HOME"]).expanduser().resolve()
        path.mkdir(parents=True, exist_ok=True)
    else:
        path = home() / "dagster"
        path.mkdir(parents=True, exist_ok=True)
        if not (path / "dagster.yaml").exists():
            replace_atomically(path / "dagster.yaml", lambda tmp: shutil.copyfile(TEMPLATE, tmp), ".yaml")
    os.environ["DAGSTER_HOME"] = str(path)
    return path
