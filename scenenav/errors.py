"""User-facing errors: one line, what/where/what is expected, exit code 2 (see scenenav.cli)."""


class UserError(Exception):
    """Bad input from the user (file, key, value). The CLI prints `error: <message>` and exits 2.

    The message must name the file or key, say what was wrong, and what is expected, e.g.
    "scenario.yaml: vehicle.mass_kg = -1: expected a positive number".
    """

    exit_code = 2
