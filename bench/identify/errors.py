"""The one error identification raises: the logs cannot be identified, said in one line."""

from drivers import BenchError

__all__ = ["IdentifyError"]


class IdentifyError(BenchError, ValueError):
    """The logs cannot be identified together (missing, not the rig's, two different rigs)."""
