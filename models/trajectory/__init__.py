"""Trajectory imitation (thesis chapters 6-7): environment, learners, baselines, metrics, prediction."""
