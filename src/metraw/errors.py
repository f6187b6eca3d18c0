"""User-facing errors: one clear line, non-zero exit from the CLI."""


class MetrawError(Exception):
    """An error caused by the user's input or environment, reported as one line."""
