"""The command line's exit codes and the usage error it maps to exit 2 (``dtmbnav.cli``'s docstring lists them)."""

EXIT_OK = 0
EXIT_NO_RESULT = 1
EXIT_USAGE = 2
EXIT_BAD_INPUT = 3
EXIT_INTERNAL = 4
#: Ctrl-C without the handlers of ``dtmbnav_core.interrupt`` (outside the main thread): 128 + SIGINT.
EXIT_INTERRUPTED = 130


class UsageError(Exception):
    """A usage error found after parsing, before any work (exit 2)."""
