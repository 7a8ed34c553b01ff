"""tracker/capture/v4l2_abi.py against the kernel's own UAPI headers, compiled with gcc.

Every structure size, ioctl number and constant the V4L2 backend uses is
printed by a C program built against <linux/media.h>, <linux/videodev2.h> and
<linux/v4l2-subdev.h> and compared with the Python transcription. The host
is 64-bit like the Pi 5's arm64, where these layouts are the same.
"""

import ctypes
import shutil
import subprocess
from pathlib import Path

import pytest

from tracker.capture import v4l2_abi as abi

GCC = shutil.which("gcc")
pytestmark = pytest.mark.skipif(
    GCC is None or not Path("/usr/include/linux/videodev2.h").exists(),
    reason="gcc or the kernel headers (linux-libc-dev) are missing")

STRUCTS = {
    "MediaDeviceInfo": "media_device_info", "MediaV2Topology": "media_v2_topology",
    "MediaV2Entity": "media_v2_entity", "MediaV2Interface": "media_v2_interface",
    "MediaV2Pad": "media_v2_pad", "MediaV2Link": "media_v2_link",
    "MediaPadDesc": "media_pad_desc", "MediaLinkDesc": "media_link_desc",
    "MbusFramefmt": "v4l2_mbus_framefmt", "SubdevFormat": "v4l2_subdev_format",
    "PixFormat": "v4l2_pix_format", "Format": "v4l2_format",
    "RequestBuffers": "v4l2_requestbuffers", "Buffer": "v4l2_buffer",
    "ExtControl": "v4l2_ext_control", "ExtControls": "v4l2_ext_controls",
    "QueryCtrl": "v4l2_queryctrl",
}
OFFSETS = [("Buffer", "v4l2_buffer", f) for f in ("timestamp", "sequence", "m", "length")] + \
    [("ExtControl", "v4l2_ext_control", "value64"), ("ExtControls", "v4l2_ext_controls",
                                                     "controls"),
     ("MediaV2Interface", "media_v2_interface", "devnode"),
     ("MediaV2Topology", "media_v2_topology", "ptr_links")]
_PY_FIELD = {"value64": "u", "devnode": "u"}


def test_structures_ioctls_and_constants_match_the_kernel_headers(tmp_path):
    lines = ["#include <stdio.h>", "#include <stddef.h>", "#include <linux/media.h>",
             "#include <linux/videodev2.h>", "#include <linux/v4l2-subdev.h>",
             "#include <linux/media-bus-format.h>", "int main(void) {"]
    lines += [f'printf("size {py} %zu\\n", sizeof(struct {c}));' for py, c in STRUCTS.items()]
    lines += [f'printf("offset {py}.{f} %zu\\n", offsetof(struct {c}, {f}));'
              for py, c, f in OFFSETS]
    lines += [f'printf("ioctl {name} %lu\\n", (unsigned long){name});' for name in abi.IOCTL]
    lines += [f'printf("const {name} %u\\n", (unsigned int)({name}));' for name in abi.CONST]
    lines += ["return 0;", "}"]
    src = tmp_path / "abi.c"
    src.write_text("\n".join(lines) + "\n")
    exe = tmp_path / "abi"
    subprocess.run([GCC, "-o", str(exe), str(src)], check=True, capture_output=True, text=True)
    out = subprocess.run([str(exe)], check=True, capture_output=True, text=True).stdout
    kernel = {tuple(line.split()[:2]): int(line.split()[2]) for line in out.splitlines()}
    ours = {("size", py): ctypes.sizeof(getattr(abi, py)) for py in STRUCTS}
    ours.update({("offset", f"{py}.{f}"): getattr(getattr(abi, py), _PY_FIELD.get(f, f)).offset
                 for py, _, f in OFFSETS})
    ours.update({("ioctl", k): v for k, v in abi.IOCTL.items()})
    ours.update({("const", k): v for k, v in abi.CONST.items()})
    assert ours == kernel
