"""Trajectory-imitation assets (issue 3): exposes ASSETS, CHECKS and JOBS for pipelines.definitions."""

ASSETS: list = []
CHECKS: list = []
JOBS: list = []
