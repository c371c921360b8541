"""The Dagster code location (definitions.py), its launchers and its logger.

Every process that imports the pipelines (Dagster's run workers, `python -m pipelines.materialize`) imports this first:
the allocators are set here, before any asset module loads polars (models/memory.py says why)."""

from models.memory import keep_freed_memory

keep_freed_memory()
