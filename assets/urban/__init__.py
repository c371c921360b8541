"""Urban traffic assets (issue 4): exposes ASSETS, CHECKS and JOBS for pipelines.definitions."""

ASSETS: list = []
CHECKS: list = []
JOBS: list = []
