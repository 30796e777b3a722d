"""Files: history.nc (netCDF, CF-style), snapshots.nc and the ParaView files, the checkpoint,
atomic writes, the netCDF helpers, and the rules of an output folder.

May import: sim, config, _kernels (the records' layouts only). Stores what sim.diagnostics
computes; computes no physics.
"""
