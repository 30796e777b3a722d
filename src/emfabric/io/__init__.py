"""Output files: history (netCDF), snapshots (netCDF + ParaView VTU/PVD)."""
