"""Errors the user can fix: bad input files, bad settings.

The CLI prints these as one line (no traceback) and exits with code 2. Always name the file
and say what was expected.
"""


class InputError(Exception):
    """A problem with the user's input (capture folder, config file, run directory)."""
