"""The Pi 5's camera pipeline set up through the kernel's media controller (no libcamera).

On a Pi 5 the sensor sits behind the RP1 camera front end (driver rp1-cfe,
drivers/media/platform/raspberrypi/rp1_cfe/ in the Raspberry Pi kernel). Its
media graph, as ``cfe.c`` and ``csi2.c`` build it::

    "<sensor>":0 -> "csi2":0          [ENABLED, IMMUTABLE]
    "csi2":4 -> "rp1-cfe-csi2_ch0":0  [] (disabled at boot)
    "csi2":4 -> "pisp-fe":0           [] (libcamera enables this one)
    "csi2":5 -> "rp1-cfe-embedded":0  [] ...

To stream raw frames from ``rp1-cfe-csi2_ch0`` without libcamera:

1. find the media device whose model is ``rp1-cfe`` and whose ``csi2``
   entity has a sensor on pad 0 (by entity names and functions: /dev/mediaN
   and /dev/videoN numbers change between boots);
2. disable every other enabled link (the CFE starts the sensor only when
   every node with an enabled link is streaming, so a link left by
   libcamera would stall it), and enable ``csi2``:4 -> ``rp1-cfe-csi2_ch0``;
3. set the same format on the sensor's source pad and ``csi2``'s sink pad 0
   (which the driver copies to source pad 4), and the matching pixel format
   on the video node: for a 10-bit mono sensor ``Y10_1X10`` with ``Y10P``
   (CSI-2 packed) or ``Y16`` (the CFE unpacks to 16-bit words); ``Y8_1X8``
   with ``GREY``. A mismatch makes STREAMON fail with EPIPE.

Exposure, analogue gain and the frame length (vertical blanking) are
controls of the sensor's own subdevice, not of the video node.

This module talks to the kernel through :class:`DeviceIO` (os, fcntl, mmap,
select), which tests replace with a simulated device layer; the structures
are :mod:`tracker.capture.v4l2_abi`. The choice of ioctls over Debian's
v4l-utils (``media-ctl``, ``v4l2-ctl``) keeps the set-up inside the service,
repeated at every open (any libcamera application run in between changes
it), with errors it can report; v4l-utils stays installed for people to look
(``media-ctl -p``).
"""

from __future__ import annotations

import ctypes as C
import errno
import fcntl
import mmap
import os
import re
import select
from dataclasses import dataclass, field
from pathlib import Path

from tracker.capture import v4l2_abi as abi
from tracker.capture.live import CameraError

__all__ = ["DeviceIO", "MediaGraph", "Entity", "Link", "StreamFormat", "STREAM_FORMATS",
           "Pipeline", "find_pipeline", "CFE_MODEL", "CSI2", "VIDEO_NODE"]

CFE_MODEL = "rp1-cfe"
CSI2 = "csi2"
VIDEO_NODE = "rp1-cfe-csi2_ch0"
_CSI2_SOURCE_PAD = 4         # csi2 pads 0..3 are sinks, 4..7 the matching sources
_K = abi.CONST


class DeviceIO:
    """The kernel, as the V4L2 backend uses it; tests substitute a simulated one."""

    def media_devices(self) -> list[str]:
        """/dev/mediaN paths, in N order."""
        found = Path("/dev").glob("media*")
        return [str(p) for p in sorted(found, key=lambda p: int(re.sub(r"\D", "", p.name) or 0))]

    def char_device_path(self, major: int, minor: int) -> str | None:
        """The /dev path of a character device number (from sysfs), or None."""
        try:
            uevent = Path(f"/sys/dev/char/{major}:{minor}/uevent").read_text()
        except OSError:
            return None
        name = re.search(r"^DEVNAME=(.+)$", uevent, re.M)
        return f"/dev/{name.group(1)}" if name else None

    def open(self, path: str) -> int:
        return os.open(path, os.O_RDWR | os.O_NONBLOCK | os.O_CLOEXEC)

    def close(self, fd: int) -> None:
        os.close(fd)

    def ioctl(self, fd: int, name: str, arg) -> None:
        """Run ioctl ``name`` (a key of v4l2_abi.IOCTL) on arg in place; OSError on failure."""
        fcntl.ioctl(fd, abi.IOCTL[name], arg, True)

    def mmap(self, fd: int, length: int, offset: int):
        return mmap.mmap(fd, length, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE,
                         offset=offset)

    def poll(self, fd: int, timeout_s: float) -> bool:
        """True when a buffer is ready to be dequeued within timeout_s."""
        p = select.poll()
        p.register(fd, select.POLLIN | select.POLLPRI | select.POLLERR)
        return bool(p.poll(int(timeout_s * 1000)))


# ---- the graph -----------------------------------------------------------------


@dataclass
class Entity:
    id: int
    name: str
    function: int
    pads: dict[int, int] = field(default_factory=dict)     # pad index -> pad id
    devnode: str | None = None


@dataclass
class Link:
    id: int
    source: tuple[int, int]        # (entity id, pad index)
    sink: tuple[int, int]
    flags: int

    @property
    def enabled(self) -> bool:
        return bool(self.flags & _K["MEDIA_LNK_FL_ENABLED"])

    @property
    def immutable(self) -> bool:
        return bool(self.flags & _K["MEDIA_LNK_FL_IMMUTABLE"])


@dataclass
class MediaGraph:
    """Entities and data links of one media device (MEDIA_IOC_G_TOPOLOGY)."""

    model: str
    entities: dict[int, Entity]
    links: list[Link]

    @classmethod
    def read(cls, io: DeviceIO, fd: int) -> MediaGraph:
        info = abi.MediaDeviceInfo()
        io.ioctl(fd, "MEDIA_IOC_DEVICE_INFO", info)
        topo = abi.MediaV2Topology()
        io.ioctl(fd, "MEDIA_IOC_G_TOPOLOGY", topo)          # first call: the counts
        ents = (abi.MediaV2Entity * topo.num_entities)()
        intfs = (abi.MediaV2Interface * topo.num_interfaces)()
        pads = (abi.MediaV2Pad * topo.num_pads)()
        links = (abi.MediaV2Link * topo.num_links)()
        for name, array in (("entities", ents), ("interfaces", intfs), ("pads", pads),
                            ("links", links)):
            setattr(topo, f"ptr_{name}", C.addressof(array))
        io.ioctl(fd, "MEDIA_IOC_G_TOPOLOGY", topo)          # second call: the arrays
        entities = {e.id: Entity(e.id, e.name.decode(errors="replace"), e.function)
                    for e in ents}
        pad_of = {p.id: (p.entity_id, p.index) for p in pads}
        for p in pads:
            entities[p.entity_id].pads[p.index] = p.id
        intf_of = {i.id: i for i in intfs}
        out = []
        for link in links:
            kind = link.flags & _K["MEDIA_LNK_FL_LINK_TYPE"]
            if kind == _K["MEDIA_LNK_FL_INTERFACE_LINK"]:
                intf = intf_of.get(link.source_id)
                if intf is not None and link.sink_id in entities:
                    dev = intf.u.devnode
                    entities[link.sink_id].devnode = io.char_device_path(dev.major, dev.minor)
            elif kind == _K["MEDIA_LNK_FL_DATA_LINK"] and link.source_id in pad_of:
                out.append(Link(link.id, pad_of[link.source_id], pad_of[link.sink_id],
                                link.flags))
        return cls(info.model.decode(errors="replace"), entities, out)

    def by_name(self, name: str) -> Entity | None:
        return next((e for e in self.entities.values() if e.name == name), None)

    def sensor_on(self, entity: Entity, pad: int) -> tuple[Entity, int] | None:
        """The camera sensor (and its source pad) linked to ``entity``:``pad``."""
        for link in self.links:
            if link.sink == (entity.id, pad):
                src = self.entities[link.source[0]]
                if src.function == _K["MEDIA_ENT_F_CAM_SENSOR"]:
                    return src, link.source[1]
        return None


# ---- formats ---------------------------------------------------------------------


@dataclass(frozen=True)
class StreamFormat:
    """A capture.raw_format as the CFE delivers it."""

    raw_format: str        # tracker.capture.rawformat name of what the node writes
    mbus_code: int         # on the sensor's and csi2's pads
    pixelformat: int       # on the video node
    fourcc: str


STREAM_FORMATS = {
    "R16": StreamFormat("R16", _K["MEDIA_BUS_FMT_Y10_1X10"], _K["V4L2_PIX_FMT_Y16"], "Y16 "),
    "R10_CSI2P": StreamFormat("R10_CSI2P", _K["MEDIA_BUS_FMT_Y10_1X10"],
                              _K["V4L2_PIX_FMT_Y10P"], "Y10P"),
    "R8": StreamFormat("R8", _K["MEDIA_BUS_FMT_Y8_1X8"], _K["V4L2_PIX_FMT_GREY"], "GREY"),
    "R8_CSI2P": StreamFormat("R8", _K["MEDIA_BUS_FMT_Y8_1X8"], _K["V4L2_PIX_FMT_GREY"],
                             "GREY"),
}


def _fourcc_text(value: int) -> str:
    return "".join(chr((value >> (8 * k)) & 0xFF) for k in range(4))


# ---- the pipeline ----------------------------------------------------------------


@dataclass
class Pipeline:
    """An rp1-cfe graph set up for raw capture: device paths and the formats granted."""

    media: str
    sensor: str
    sensor_subdev: str
    csi2_subdev: str
    video: str
    fmt: StreamFormat
    width: int
    height: int
    bytesperline: int
    sizeimage: int
    disabled_links: int

    def describe(self) -> str:
        return (f"{self.media}: {self.sensor} -> csi2 -> {VIDEO_NODE} ({self.video}), "
                f"{self.width}x{self.height} {self.fmt.fourcc.strip()}, "
                f"{self.bytesperline} bytes per line; {self.disabled_links} other link(s) "
                "disabled")


def _ioctl(io: DeviceIO, fd: int, name: str, arg, what: str) -> None:
    try:
        io.ioctl(fd, name, arg)
    except OSError as exc:
        raise CameraError(f"{what}: {name} failed: {os.strerror(exc.errno or 0)}") from None


def _choose(io: DeviceIO, device: str) -> tuple[str, MediaGraph, Entity, Entity, int]:
    """(media path, graph, csi2, sensor, sensor pad) of the rp1-cfe picked by ``device``."""
    candidates = []
    paths = [device] if device.startswith("/dev/") else io.media_devices()
    for path in paths:
        try:
            fd = io.open(path)
        except OSError as exc:
            if device.startswith("/dev/"):
                raise CameraError(f"cannot open {path}: {exc.strerror}") from None
            continue
        try:
            graph = MediaGraph.read(io, fd)
        except OSError:
            continue
        finally:
            io.close(fd)
        csi2 = graph.by_name(CSI2)
        if graph.model != CFE_MODEL or csi2 is None:
            continue
        found = graph.sensor_on(csi2, 0)
        if found is not None:
            candidates.append((path, graph, csi2, *found))
    index = 0 if device.startswith("/dev/") else int(device) if device.isdigit() else -1
    if not 0 <= index < len(candidates):
        looked = ", ".join(paths) or "no /dev/media* at all"
        raise CameraError(f"no {CFE_MODEL} media device with a sensor on csi2 (number "
                          f"{device!r}; looked at {looked}): is the camera connected and "
                          "its dtoverlay set (firmware_config/config.txt.fragment)?")
    return candidates[index]


def _set_links(io: DeviceIO, fd: int, graph: MediaGraph, csi2: Entity, node: Entity) -> int:
    """Disable every other mutable enabled link; enable csi2:4 -> the video node."""
    want = ((csi2.id, _CSI2_SOURCE_PAD), (node.id, 0))
    disabled = 0
    for link in graph.links:
        if (link.source, link.sink) == want or link.immutable or not link.enabled:
            continue
        _setup_link(io, fd, link.source, link.sink, 0, graph)
        disabled += 1
    _setup_link(io, fd, *want, _K["MEDIA_LNK_FL_ENABLED"], graph)
    return disabled


def _setup_link(io, fd, source, sink, flags, graph) -> None:
    desc = abi.MediaLinkDesc()
    desc.source.entity, desc.source.index = source
    desc.sink.entity, desc.sink.index = sink
    desc.flags = flags
    names = f'"{graph.entities[source[0]].name}":{source[1]} -> ' \
            f'"{graph.entities[sink[0]].name}":{sink[1]}'
    _ioctl(io, fd, "MEDIA_IOC_SETUP_LINK", desc, f"link {names} [{flags}]")


def _subdev_format(io: DeviceIO, fd: int, pad: int, width: int, height: int, code: int,
                   what: str) -> abi.MbusFramefmt:
    f = abi.SubdevFormat(which=_K["V4L2_SUBDEV_FORMAT_ACTIVE"], pad=pad)
    f.format.width, f.format.height, f.format.code = width, height, code
    f.format.field = _K["V4L2_FIELD_NONE"]
    f.format.colorspace = _K["V4L2_COLORSPACE_RAW"]
    _ioctl(io, fd, "VIDIOC_SUBDEV_S_FMT", f, what)
    got = f.format
    if (got.width, got.height, got.code) != (width, height, code):
        raise CameraError(f"{what} pad {pad}: asked for {width}x{height} code 0x{code:04x}, "
                          f"granted {got.width}x{got.height} code 0x{got.code:04x}")
    return got


def _read_subdev_format(io: DeviceIO, fd: int, pad: int, what: str) -> abi.MbusFramefmt:
    f = abi.SubdevFormat(which=_K["V4L2_SUBDEV_FORMAT_ACTIVE"], pad=pad)
    _ioctl(io, fd, "VIDIOC_SUBDEV_G_FMT", f, what)
    return f.format


def _video_format(io: DeviceIO, fd: int, fmt: StreamFormat, width: int,
                  height: int) -> abi.PixFormat:
    f = abi.Format(type=_K["V4L2_BUF_TYPE_VIDEO_CAPTURE"])
    pix = f.fmt.pix
    pix.width, pix.height, pix.pixelformat = width, height, fmt.pixelformat
    pix.field = _K["V4L2_FIELD_NONE"]
    _ioctl(io, fd, "VIDIOC_S_FMT", f, VIDEO_NODE)
    if (pix.width, pix.height, pix.pixelformat) != (width, height, fmt.pixelformat):
        raise CameraError(f"{VIDEO_NODE}: asked for {width}x{height} {fmt.fourcc!r}, granted "
                          f"{pix.width}x{pix.height} {_fourcc_text(pix.pixelformat)!r}")
    return pix


def find_pipeline(io: DeviceIO, device: str, raw_format: str,
                  shape: tuple[int, int]) -> Pipeline:
    """Find the rp1-cfe graph, link it and set every format (module docstring).

    ``device``: the rp1-cfe's number among those with a sensor, or /dev/mediaN.
    ``shape``: (rows, cols). Raises CameraError saying which step failed.
    """
    if raw_format not in STREAM_FORMATS:
        raise CameraError(f"capture.raw_format {raw_format!r}: rp1-cfe delivers "
                          f"{', '.join(STREAM_FORMATS)}")
    fmt = STREAM_FORMATS[raw_format]
    rows, cols = shape
    path, graph, csi2, sensor, sensor_pad = _choose(io, device)
    node = graph.by_name(VIDEO_NODE)
    if node is None or node.devnode is None or sensor.devnode is None or csi2.devnode is None:
        raise CameraError(f"{path}: no device node for {VIDEO_NODE}, the sensor or csi2")
    fd = io.open(path)
    try:
        disabled = _set_links(io, fd, graph, csi2, node)
    finally:
        io.close(fd)
    for entity, pad in ((sensor, sensor_pad), (csi2, 0)):
        fd = io.open(entity.devnode)
        try:
            _subdev_format(io, fd, pad, cols, rows, fmt.mbus_code, f'"{entity.name}"')
            if entity is csi2:
                src = _read_subdev_format(io, fd, _CSI2_SOURCE_PAD, CSI2)
                if (src.width, src.height, src.code) != (cols, rows, fmt.mbus_code):
                    raise CameraError(f"csi2 pad 4 did not take pad 0's format: {src.width}x"
                                      f"{src.height} code 0x{src.code:04x}")
        finally:
            io.close(fd)
    fd = io.open(node.devnode)
    try:
        pix = _video_format(io, fd, fmt, cols, rows)
    finally:
        io.close(fd)
    return Pipeline(path, sensor.name, sensor.devnode, csi2.devnode, node.devnode, fmt, cols,
                    rows, pix.bytesperline, pix.sizeimage, disabled)


def stream_errno_text(err: int) -> str:
    """What a STREAMON failure means on rp1-cfe."""
    if err == errno.EPIPE:
        return "the pads' formats do not match (EPIPE)"
    if err == errno.EINVAL:
        return "the node's link is not enabled (EINVAL)"
    if err == errno.EBUSY:
        return "the device is busy (another process streams from it: libcamera, the service?)"
    return os.strerror(err)
