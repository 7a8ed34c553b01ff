"""The daemon's operating mode: the ICD's Mode, and the rules that move it.

One concept, one name: the daemon's mode is the
:class:`~tracker.protocol.messages.Mode` that ATTITUDE and STATUS report.

- ``STANDBY``: frames are taken but not processed (ATTITUDE goes on with
  VALID clear) until the FC asks for a mode.
- ``LOST_IN_SPACE``: frames are solved with no prior attitude.
- ``TRACKING``: ``service.track_after`` solved frames in a row; back to
  LOST_IN_SPACE after ``service.lost_after`` unsolved ones.
- ``FAULT``: the camera is absent or failed, or ``service.fault_after``
  frames in a row failed. Left for the mode the FC asked for (STANDBY or
  LOST_IN_SPACE) on the next good frame.

The FC asks with SET_MODE: STANDBY, LOST_IN_SPACE (forget the lock and solve
from scratch) or TRACKING (keep any lock; the daemon tracks by itself once
frames solve). What it asked is kept while in FAULT and applied on leaving.
"""

from __future__ import annotations

import logging

from tracker.config import ServiceConfig
from tracker.protocol.messages import Mode

__all__ = ["ModeMachine", "START_MODES"]

log = logging.getLogger(__name__)

# service.start_state -> Mode
START_MODES = {"standby": Mode.STANDBY, "lost_in_space": Mode.LOST_IN_SPACE}


class ModeMachine:
    """The current :attr:`mode` and the one the FC wants; see the module docstring."""

    def __init__(self, cfg: ServiceConfig):
        self.cfg = cfg
        self.wanted = START_MODES[cfg.start_state]
        self.mode = self.wanted
        self._solved_run = self._missed_run = self._failed_run = 0

    @property
    def processing(self) -> bool:
        """Whether frames go through the pipeline (not in STANDBY)."""
        return self.mode != Mode.STANDBY

    def command(self, mode: Mode) -> None:
        """SET_MODE from the FC (STANDBY, LOST_IN_SPACE or TRACKING)."""
        self.wanted = Mode.STANDBY if mode == Mode.STANDBY else Mode.LOST_IN_SPACE
        if self.mode == Mode.FAULT:
            return
        if mode == Mode.TRACKING and self.mode == Mode.TRACKING:
            return
        self._enter(self.wanted)

    def camera_lost(self) -> None:
        """The camera failed or could not be opened."""
        self._enter(Mode.FAULT)

    def frame_failed(self) -> None:
        """A frame was lost (unreadable, late, or a stage failed on it)."""
        self._failed_run += 1
        if self._failed_run >= self.cfg.fault_after:
            self._enter(Mode.FAULT)

    def frame_ok(self) -> None:
        """A good frame arrived: a FAULT ends."""
        self._failed_run = 0
        if self.mode == Mode.FAULT:
            self._enter(self.wanted)

    def solved(self, ok: bool) -> None:
        """A processed frame was solved (ok) or not."""
        if ok:
            self._solved_run += 1
            self._missed_run = 0
            if self.mode == Mode.LOST_IN_SPACE and self._solved_run >= self.cfg.track_after:
                self._enter(Mode.TRACKING)
        else:
            self._missed_run += 1
            self._solved_run = 0
            if self.mode == Mode.TRACKING and self._missed_run >= self.cfg.lost_after:
                self._enter(Mode.LOST_IN_SPACE)

    def _enter(self, mode: Mode) -> None:
        if mode != self.mode:
            log.info("mode %s -> %s", self.mode.name, mode.name)
            self.mode = mode
            self._solved_run = self._missed_run = 0
