"""Air traffic congestion (DCB) assets (issue 5): exposes ASSETS, CHECKS and JOBS for pipelines.definitions."""

ASSETS: list = []
CHECKS: list = []
JOBS: list = []
