"""Where the Dagster instance lives when a command is run without the Makefile (which sets DAGSTER_HOME)."""

import os
import shutil
from pathlib import Path

from warehouse.storage import home, replace_atomically

TEMPLATE = Path(__file__).resolve().parent.parent / "dagster.yaml"


class InstanceError(ValueError):
    """The instance's folder cannot be made (one line)."""


def dagster_home() -> Path:
    """$DAGSTER_HOME if set; else $TRAFFICLEARN_HOME/dagster, as `make` sets it, with the checkout's dagster.yaml
    copied in when it has none or an older one (the Makefile's rule: a changed checkout reaches the instance however
    the command is run). Exported, so that Dagster and its child processes use it too."""
    given = bool(os.environ.get("DAGSTER_HOME"))
    path = Path(os.environ["DAGSTER_HOME"]).expanduser().resolve() if given else home() / "dagster"
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:  # a file there, or a file on the way (e.g. TRAFFICLEARN_HOME)
        raise InstanceError(f"{'DAGSTER_HOME' if given else 'the Dagster instance'} {path}: not a usable folder ({e.strerror})") from None
    own = path / "dagster.yaml"
    if not given and (not own.exists() or own.stat().st_mtime < TEMPLATE.stat().st_mtime):
        replace_atomically(own, lambda tmp: shutil.copyfile(TEMPLATE, tmp), ".yaml")
    os.environ["DAGSTER_HOME"] = str(path)
    return path
