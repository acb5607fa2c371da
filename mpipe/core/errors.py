"""Errors that the user can fix, reported as one line by the command line."""

from __future__ import annotations


class UserError(Exception):
    """A problem with the user's input: a file, a channel, an option or a value.

    The message must name the file, key or channel and say what was expected.
    """


class OutputExistsError(UserError):
    """An output would overwrite existing results and ``--force`` was not given."""
