"""Reading sources: the first step of the data path.

    adapters/   one adapter per raw recording format (OpenTouch HDF5, TouchAnything folders, native)
    sync.py     pair the tactile and RGB clocks (nearest neighbour within a tolerance)
    lag.py      estimate a constant clock lag between the streams
    syncsettings.py  a pipeline's [sync] section: the pairing tolerance and the clock lag setting
    rgb.py      RGB frames: channel order, square crop, resize to the canvas
    rgbsettings.py   a pipeline's [rgb] section: size, crop, interpolation, JPEG quality, unpaired frames

May import: htdata's base modules (errors, faults, fileio, resources, settings), htdata.format and htdata.glove.
Never the store, reading, curation or the commands above it.
"""
