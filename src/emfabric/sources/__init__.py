"""Every field source, on the Python side: the Field record built from a scenario (uniform fields,
loops and solenoids with their current waveforms, permanent magnets, field maps), the source
grid that precomputes coils and magnets over the region the fabric can reach, the field at
points outside a run, the field figure's samples, and field design's scaling of the sources.

The field inside the kernels is emfabric._kernels.fields (``field_at``) and
emfabric._kernels.coils (the loop's closed forms). May import: config, _kernels.
"""
