"""User-facing errors: one line, what/where/what is expected, exit code 2 (see scenenav.app.cli)."""


class UserError(Exception):
    """Bad input from the user (file, key, value). The CLI prints `error: <message>` and exits 2.

    The message must name the file or key, say what was wrong, and what is expected, e.g.
    "scenario.yaml: vehicle.mass_kg = -1: expected a positive number".
    """

    exit_code = 2


def run_command(args) -> int:
    """Run a parsed command (``args.func(args)``) the way every entry point does: a UserError
    becomes one ``error: ...`` line on stderr and its exit code, Ctrl-C exits 130."""
    import sys
    try:
        return int(args.func(args) or 0)
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
