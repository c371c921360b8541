"""The route agents trained for one (scenario, method, seed) as one file: their stacked weights, the route agents
in weight order and how they were trained. No Dagster here.

Saved with torch.save as a dict tagged FORMAT, the weights as tensors, so loading never unpickles code
(weights_only). Files written before the tag (numpy weights, no "format") still load.
"""

import io
from pathlib import Path

import numpy as np
import polars as pl
import torch

FORMAT = "trafficlearn.urban_policy.v1"
# what an untagged file of the first version pickled besides tensors: numpy float32 arrays
_LEGACY_GLOBALS = [np._core.multiarray._reconstruct, np.ndarray, np.dtype, np.dtypes.Float32DType]


class PolicyFileError(ValueError):
    """A policy file that cannot be used; the message is one line naming the file."""


def policy_bytes(params: dict[str, np.ndarray], agents: list[str], leader_guard: bool, **trained) -> bytes:
    """The file's content: numpy weights (col_marl.numpy_params), route agents, the leader guard the policies keep
    for evaluation, and `trained` (variant, scenario, seed, episodes, gradient_steps: provenance, not read back)."""
    buffer = io.BytesIO()
    torch.save({"format": FORMAT, "params": {k: torch.from_numpy(v) for k, v in params.items()}, "agents": list(agents),
                "leader_guard": bool(leader_guard), **trained}, buffer)
    return buffer.getvalue()


def load_policy(path: str | Path) -> dict:
    """The saved dict with numpy weights (`params`), `agents` and `leader_guard` (False in files from before the
    guard); a one-line PolicyFileError for a missing file, a file that is not a policy file or one of another format."""
    path = Path(path)
    if not path.is_file():
        raise PolicyFileError(f"policy file {path}: not found")
    try:
        with torch.serialization.safe_globals(_LEGACY_GLOBALS):
            blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 — torch raises many kinds for a corrupt or foreign file
        raise PolicyFileError(f"policy file {path}: not an urban policy file ({type(exc).__name__})") from None
    if isinstance(blob, dict) and blob.get("format", FORMAT) != FORMAT:  # untagged: the first version
        raise PolicyFileError(f"policy file {path}: format {blob['format']!r}, this trafficlearn reads {FORMAT}")
    if not isinstance(blob, dict) or not {"params", "agents"} <= blob.keys() or not isinstance(blob["params"], dict):
        raise PolicyFileError(f"policy file {path}: not an urban policy file (no route agents and weights)")
    return {**blob, "params": {k: np.asarray(v) for k, v in blob["params"].items()}, "leader_guard": blob.get("leader_guard", False)}


def load_policies(training: pl.DataFrame) -> dict:
    """(scenario, method) -> {seed: (agents, numpy params, leader_guard)} from the model files listed in urban_training."""
    out: dict = {}
    for scenario, method, seed, path in training.select("scenario", "method", "seed", "model_path").unique().sort("seed").iter_rows():
        policy = load_policy(path)
        out.setdefault((scenario, method), {})[seed] = (policy["agents"], policy["params"], policy["leader_guard"])
    return out
