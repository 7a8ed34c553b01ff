"""A stand-in for picamera2's Picamera2 that keeps its request and job life cycle.

Read from picamera2's own source (picamera2.py, job.py, request.py, 0.3.20
to 0.3.36): a capture is a *job* queued in ``_job_list``; each frame the
camera completes runs the oldest job, which takes the request (one "use" of
its buffer) and hands it to the caller, who must release it. A job that
timed out (``wait(job, timeout)`` raised TimeoutError) is NOT removed: it
stays queued, takes the next frame's request, and nobody releases it: the
buffer leaks. ``stop()`` runs as another job behind the queued ones, so with a
stale job and no more frames (all buffers leaked) it waits for ever; this
fake raises instead, so a test fails rather than hangs. ``cancel_all_and_flush()``
cancels the queued jobs (their results raise CancelledError) and empties the
queue.

Time is a script, not a clock: each ``wait()`` call takes one event from
``script``: "frame" (the camera completes a frame during this wait) or
"nothing". A frame needs a free buffer; with none left the camera starves.
"""

import contextlib
from concurrent.futures import CancelledError, Future

import numpy as np


class FakeRequest:
    def __init__(self, cam, buf, md):
        self.cam, self.buf, self.md = cam, buf, md
        self.released = False

    def get_metadata(self):
        return dict(self.md)

    def release(self):
        assert not self.released, "request released twice"
        self.released = True
        self.cam.free_buffers += 1


class FakeMappedArray:
    """Maps the request's buffer; records whether write access was asked for."""

    writes = []

    def __init__(self, request, stream, reshape=True, write=True):
        assert stream == "raw"
        FakeMappedArray.writes.append(write)
        self.array = request.buf if write else request.buf.view()
        if not write:
            self.array.flags.writeable = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


class FakeJob:
    def __init__(self):
        self._future = Future()
        self._future.set_running_or_notify_cancel()

    def get_result(self, timeout=None):
        return self._future.result(timeout=timeout)

    def cancel(self):
        self._future.set_exception(CancelledError())


class FakePicamera2:
    """See the module docstring. ``frames`` yields (buffer, metadata) for each frame."""

    def __init__(self, script, frames, buffer_count=4, granted="R16",
                 with_cancel=True, fail_in=None):
        self.script = list(script)
        self.frames = frames
        self.granted = granted
        self.buffer_count = buffer_count
        self.free_buffers = 0
        self._job_list = []
        self.config = self.controls = None
        self.started = self.closed = False
        self.fail_in = fail_in          # "configure" or "start": raise there
        if not with_cancel:
            self.cancel_all_and_flush = None

    # -- configuration ---------------------------------------------------------

    def create_still_configuration(self, **kw):
        return kw

    def configure(self, config):
        if self.fail_in == "configure":
            raise ValueError("Unexpected keys in sensor configuration")
        self.config = config
        self.free_buffers = config.get("buffer_count", self.buffer_count)

    def camera_configuration(self):
        return {"raw": {"format": self.granted, "size": self.config["raw"]["size"]}}

    def start(self):
        if self.fail_in == "start":
            raise RuntimeError("Failed to start camera: Device or resource busy")
        self.started = True

    def set_controls(self, controls):
        self.controls = controls

    # -- the request/job cycle -------------------------------------------------

    def _frame(self):
        if not self.started or self.free_buffers == 0:
            return                        # stopped, or every buffer leaked: starved
        buf, md = next(self.frames)
        self.free_buffers -= 1
        request = FakeRequest(self, buf, md)
        if self._job_list:
            self._job_list.pop(0)._future.set_result(request)   # the job takes the use
        else:
            request.release()             # nobody asked: recycled to the camera

    def capture_request(self, wait=None, signal_function=None, flush=None):
        job = FakeJob()
        self._job_list.append(job)
        if wait is False:
            return job
        return self.wait(job, timeout=None if wait in (None, True) else wait)

    def wait(self, job, timeout=None):
        if self.script and self.script.pop(0) == "frame":
            self._frame()
        if job._future.done():
            return job.get_result()
        if timeout is None:
            raise AssertionError("a wait with no timeout and no frame: would hang")
        raise TimeoutError()

    @contextlib.contextmanager
    def captured_request(self, wait=None, flush=None):
        request = self.capture_request(wait=wait, flush=flush)
        try:
            yield request
        finally:
            request.release()

    def cancel_all_and_flush(self):
        for job in self._job_list:
            job.cancel()
        self._job_list = []

    def stop(self):
        if self.started and self._job_list:
            raise AssertionError("stop() queued behind a stale capture job: blocks for ever")
        self.started = False

    def close(self):
        self.stop()
        self.closed = True


def frame_stream(buffers, md):
    """Endless (buffer, metadata): the buffers given (one array or a list), in turn."""
    buffers = [buffers] if isinstance(buffers, np.ndarray) else list(buffers)
    k = 0
    while True:
        yield np.array(buffers[k % len(buffers)]), dict(md)
        k += 1
