"""The one error identification raises: the logs cannot be identified, said in one line."""

from drivers.errors import IdentifyError

__all__ = ["IdentifyError"]


