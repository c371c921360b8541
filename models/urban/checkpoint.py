"""Resumable training: the state of one training run saved every few minutes, so that an interrupted long run (the
paper profile trains 15,000 episodes per scenario, method and seed: ~7 h each for Sc1 on 2 cores) goes on where it
stopped and ends with the numbers an uninterrupted run gives. No Dagster here.

A checkpoint is one file, torch.save'd as tensors and plain values (loaded with weights_only: no code is unpickled),
tagged with a fingerprint of everything that decides the run's numbers: its arguments, the content of the training
copies' files and the source of the code that runs episodes and updates (this folder). A checkpoint whose fingerprint
differs, or that cannot be read, is not used: the run starts afresh and overwrites it.
"""

import hashlib
import io
import json
import re
import time
from pathlib import Path

import torch

from warehouse.artifacts import write_bytes_atomic

FORMAT = "trafficlearn.urban_checkpoint.v1"
CODE = sorted(Path(__file__).parent.glob("*.py"))  # any change to the urban models invalidates a checkpoint


XML_COMMENT = re.compile(rb"<!--.*?-->", re.DOTALL)


def fingerprint(files: list[str], **arguments) -> str:
    """sha256 over the arguments (JSON), the files' bytes and the urban models' source. XML comments are left out: SUMO's
    tools stamp each file they write with its time ("generated on ..."), so a network made again is the same network."""
    h = hashlib.sha256(json.dumps(arguments, sort_keys=True, default=str).encode())
    for path in files:
        h.update(XML_COMMENT.sub(b"", Path(path).read_bytes()))
    for path in CODE:
        h.update(path.read_bytes())
    return h.hexdigest()


class Checkpoint:
    """Where one run's state goes, how often (`every_s`; 0 = after every round), and whose state it is (`fingerprint`)."""

    def __init__(self, path: Path, fingerprint: str, every_s: float = 600.0):
        self.path, self.fingerprint, self.every_s = Path(path), fingerprint, every_s
        self._last = time.monotonic()
        self.skipped: str | None = None  # why an existing file was not used, for the caller's log

    def load(self) -> dict | None:
        """The saved state of this very run, or None (no file, another run's, unreadable)."""
        if not self.path.is_file():
            return None
        try:
            blob = torch.load(self.path, map_location="cpu", weights_only=True)
        except Exception as exc:  # noqa: BLE001 — a truncated or foreign file raises many kinds
            self.skipped = f"checkpoint {self.path} unreadable ({type(exc).__name__}): starting afresh"
            return None
        if not isinstance(blob, dict) or blob.get("format") != FORMAT or blob.get("fingerprint") != self.fingerprint:
            self.skipped = f"checkpoint {self.path} is of another run (configuration, data or code changed): starting afresh"
            return None
        return blob["state"]

    def due(self) -> bool:
        return time.monotonic() - self._last >= self.every_s

    def save(self, state: dict) -> None:
        """Atomically (temp file + rename): a crash while saving leaves the previous checkpoint."""
        buffer = io.BytesIO()
        torch.save({"format": FORMAT, "fingerprint": self.fingerprint, "state": state}, buffer)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(self.path, buffer.getvalue())
        self._last = time.monotonic()
