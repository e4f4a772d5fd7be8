"""The bottom layer: contracts, keys, bus, config, errors, frames, geometry, lockstep, file formats.

It imports no other package of the project; every other package may import it.
"""
