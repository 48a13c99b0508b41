"""Outcomes the command line maps to its own exit codes (``dtmbnav.cli``), importable without the libraries.

``ValueError`` and ``OSError`` stay the libraries' way of saying "bad input" (exit 3); these two say what
they cannot.
"""


class UsageError(Exception):
    """A usage error found after parsing, before any work (exit 2)."""


class NoResult(Exception):
    """The job ran on valid input but found nothing to return (exit 1)."""
