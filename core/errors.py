"""The exception every bad input raises, so the CLI and the GUI can show one clear line."""


class InputError(ValueError):
    """Bad input: a missing, empty, corrupt or unsupported file, degenerate geometry, nonsense settings."""
