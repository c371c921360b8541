"""AppLearn inverse RL assets (chapter 6, issue 3; Dagster group `trajectory`): exposes ASSETS, CHECKS and JOBS."""

ASSETS: list = []
CHECKS: list = []
JOBS: list = []
