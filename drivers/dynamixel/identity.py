"""How an emulated servo bus says it is one, in a way no real servo ever could.

The bench records which rig ran a trial: ``sim``, ``emulated`` or ``real``. A process
knows the buses it emulates itself (``trial --emulate``), but not one served by
``hilbench emulate`` in another terminal: to the driver that is a serial port like a
U2D2's. So the driver asks the bus, once per servo at connect: a READ of
:data:`EMULATED_LENGTH` bytes at :data:`EMULATED_ADDRESS`.

Why a real servo never answers it: the address is far past the end of every X-series
control table (the longest ends below 1024), and Protocol 2.0 firmware answers a READ
outside its table with an error status (Access or Data Range Error) and no data. The
emulator answers it with :data:`EMULATED_REPLY`, error-free. A reply with those bytes and
no error is therefore the emulator's; any other answer, or none, means a real servo. The
read changes nothing on either.
"""

from __future__ import annotations

__all__ = ["EMULATED_ADDRESS", "EMULATED_LENGTH", "EMULATED_REPLY", "is_emulated_reply"]

#: A control-table address no X-series servo has (their tables end below 1024).
EMULATED_ADDRESS = 0xFFF0
#: What the emulator answers there: "EMUL" in ASCII.
EMULATED_REPLY = b"EMUL"
EMULATED_LENGTH = len(EMULATED_REPLY)


def is_emulated_reply(error: int, data: bytes) -> bool:
    """Whether a status packet to the identity READ is the emulator's (no error, its four bytes)."""
    return error & 0x7F == 0 and bytes(data) == EMULATED_REPLY
