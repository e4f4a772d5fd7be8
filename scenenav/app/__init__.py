"""The top layer: CLI, launcher, scenarios, experiments, evaluation, recorder, benchmarks.

It may import every package of the project; no domain package imports it.
"""
