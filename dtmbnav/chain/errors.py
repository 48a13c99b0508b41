"""The outcome the command line maps to exit 1 (``dtmbnav.cli``), importable without the libraries.

``ValueError`` and ``OSError`` stay the libraries' way of saying "bad input" (exit 3); this says what they
cannot.
"""


class NoResult(Exception):
    """The job ran on valid input but found nothing to return (exit 1)."""
