"""File formats every package reads: world manifest, assistant-map file, route file; and the one
way files are written whole (atomic_file)."""
