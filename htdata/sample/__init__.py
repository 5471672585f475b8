"""Synthetic raw corpus in the three source formats.

`formats` holds the writers for each source layout (OpenTouch-style HDF5,
TouchAnything-style folders, htdata-native folders); the corpus generator
and the `htdata sample` command build on them.
"""
