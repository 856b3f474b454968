"""The error the test stand raises on purpose (defined with every other in :mod:`drivers.errors`):
a log or model it cannot use, said in one line."""

from drivers.errors import StandError

__all__ = ["StandError"]
