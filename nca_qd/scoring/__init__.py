"""Scoring of generated layouts for the domains that need repair and lifelong-MAPF simulation.

- :mod:`.tasks`: the unit jobs (repair one layout, run exact RHCR on one layout and seed), as
  plain functions of plain data, so any process or cluster worker can run them.
- :mod:`.backend`: where those jobs run (a local process pool, or a Dask cluster).
- :mod:`.mapf`: one QD batch: repair -> measures -> screen (JAX) -> exact RHCR where it matters.
"""
