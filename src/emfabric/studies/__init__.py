"""Many runs: sweeps over scenario keys on Dask (sweep.py), the ballistic limit and V50
(ballistic.py), field design (design.py). A Dask worker receives scenario text, runs it and
returns the run summary. Dask and SciPy (the "studies" extra) are imported inside the functions
that need them.

May import: runner, sources, sim, io, viz (for their figures), config.
"""
