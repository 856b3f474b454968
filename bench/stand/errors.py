"""The error the test stand raises on purpose: a log or model it cannot use, said in one line."""

from drivers import BenchError

__all__ = ["StandError"]


class StandError(BenchError, ValueError):
    """A stand log or servo model that cannot be used (malformed, unknown motor, torque never on)."""
