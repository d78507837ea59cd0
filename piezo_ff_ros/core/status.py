"""Status levels every core object reports with (pure, imports nothing).

The values are those of ``diagnostic_msgs/DiagnosticStatus`` (OK 0, WARN 1, ERROR 2), so that a node publishes a
level on ``/diagnostics`` as it is, and a log line's level maps to the logger's without a table per object.
"""
from __future__ import annotations

__all__ = ["OK", "WARN", "ERROR"]

#: all well
OK = 0
#: something was lost, clamped, rejected or faulted, but the stage runs
WARN = 1
#: the stage cannot do its job (a device fault, too many losses)
ERROR = 2
