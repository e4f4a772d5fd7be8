"""Route planning around bad-matching areas: potential field and navigation function over the
assistant map (pure), route files, and the guidance node that flies the route as a MAVLink mission."""
