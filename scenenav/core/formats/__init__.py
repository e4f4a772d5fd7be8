"""File formats every package reads: world manifest, assistant-map file, route file."""
