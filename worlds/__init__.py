"""Worlds: procedural cities, world folders (orthophoto, reference map, ground truth), import, default world."""
