"""Every figure and animation. Reads output files (history.nc, snapshots.nc, a study's
results.nc) or arrays handed to it; never runs the simulator, so plotting never compiles a
kernel.

May import: io, config.
"""
