"""Exceptions that the CLI turns into a one-line message and a non-zero exit."""

from __future__ import annotations


class SparselfError(Exception):
    """Base class: a problem the user can fix (bad input, bad option), not a bug."""

    exit_code = 2


class InputError(SparselfError):
    """An input file or folder is missing, unreadable or malformed. The message names it."""


class RegistrationError(SparselfError):
    """Structure-from-motion could not register enough images."""


class OutputError(SparselfError):
    """The output location cannot be used (exists and is not empty, not writable)."""


class ConfigError(SparselfError):
    """A checkpoint or config does not match what was asked for."""
