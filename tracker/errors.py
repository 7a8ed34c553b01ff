"""The one exception type every command turns into a single line and exit status 2.

:class:`UserError` is the base of the errors a user can fix: a bad
configuration (:class:`tracker.config.ConfigError`), a missing or corrupt
catalogue (:class:`tracker.catalogue.CatalogueError`), an unreadable image
(:class:`tracker.capture.imagefile.ImageReadError`), a wrong argument. Its
message is one line for people, naming the file or option at fault.
``tracker.cli`` prints it as ``tracker COMMAND: MESSAGE`` and exits with
status 2; the service logs it, counts it and goes on. This module imports
nothing, so any layer may raise it.
"""

from __future__ import annotations

__all__ = ["UserError"]


class UserError(Exception):
    """An error the user can fix; printed as one line, exit status 2."""
