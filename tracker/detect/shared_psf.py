"""A detector's PSF taken from another detector's running estimate (tracker.detect.psf).

Windowed tracking (tracker.pipeline) detects in windows of frames whose PSF
the full-frame detector has measured and smoothed across frames: the window
detector takes that estimate as given and runs the PSF meter on its windows
only when told to (tracker.detect.default.DefaultDetector.measure_psf); what
it measures then is folded into the same running estimate, so there is one
PSF per camera, the one STATUS reports (psf_fwhm_px).
"""

from __future__ import annotations

from tracker.detect.psf import PsfEstimate, PsfTracker

__all__ = ["SharedPsf"]


class SharedPsf:
    """Stands in for a detector's own PsfTracker; ``tracker`` is the one it shares."""

    def __init__(self, tracker: PsfTracker) -> None:
        self.tracker = tracker

    def update(self, measured: PsfEstimate | None) -> PsfEstimate:
        """The estimate for this frame: the shared one as it stands, or with ``measured``
        folded in (tracker.detect.psf.PsfTracker.update)."""
        return self.tracker.current if measured is None else self.tracker.update(measured)
