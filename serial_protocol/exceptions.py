"""The project's exception tree.

It lives in the lowest package that every other one may import (``planner`` and the codec
import nothing of ours, so the planner raises plain ``ValueError``)::

    TurntableError
     +-- ConfigError(TurntableError, ValueError)    bad TOML value: file, table, key, value
     +-- CommandError(TurntableError, ValueError)   bad CLI argument or command script entry
     +-- LinkError(TurntableError, OSError)         a port that cannot be opened or used
          +-- LinkTimeout(LinkError, TimeoutError)  no reply within the ACK timeout

Expected outcomes are data, not exceptions: a firmware fault is a fault code in the log and
on the wire; a bad frame is a counter in the decoder; a bad command is a NACK.
"""

from __future__ import annotations


class TurntableError(Exception):
    """Root of every error this project raises on purpose."""


class ConfigError(TurntableError, ValueError):
    """A configuration value is missing or out of range; the message names file, table,
    key and value."""


class CommandError(TurntableError, ValueError):
    """A command-line argument or a scripted command is not valid."""


class LinkError(TurntableError, OSError):
    """A serial or CAN link cannot be opened or used."""


class LinkTimeout(LinkError, TimeoutError):
    """The peer did not answer within the timeout (after the configured retries)."""
