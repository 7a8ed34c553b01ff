"""The kernel's media-controller and V4L2 interface, as ctypes structures and ioctl numbers.

Transcribed from the UAPI headers (linux/media.h, linux/videodev2.h,
linux/v4l2-subdev.h, linux/v4l2-mediabus.h, linux/v4l2-controls.h,
linux/media-bus-format.h) for a 64-bit kernel (the Pi 5 runs arm64). Only
what the V4L2 backend uses. A test compiles a C program against the
installed headers and checks every size, ioctl number and constant here.
Pure data: nothing opens a device.
"""

from __future__ import annotations

import ctypes as C

__all__ = [
    "MediaDeviceInfo", "MediaV2Topology", "MediaV2Entity", "MediaV2Interface", "MediaV2Pad",
    "MediaV2Link", "MediaPadDesc", "MediaLinkDesc", "MbusFramefmt", "SubdevFormat",
    "PixFormat", "Format", "RequestBuffers", "Timeval", "Timecode", "Buffer",
    "ExtControl", "ExtControls", "QueryCtrl", "IOCTL", "CONST", "fourcc",
]

_IOC_WRITE, _IOC_READ = 1, 2


def _ioc(direction: int, kind: str, nr: int, struct) -> int:
    return (direction << 30) | (C.sizeof(struct) << 16) | (ord(kind) << 8) | nr


def fourcc(code: str) -> int:
    """A V4L2 four-character code (e.g. 'Y10P') as its 32-bit value."""
    a, b, c, d = (ord(ch) for ch in code)
    return a | (b << 8) | (c << 16) | (d << 24)


class _Packed(C.Structure):
    _pack_ = 1


# ---- linux/media.h ---------------------------------------------------------------


class MediaDeviceInfo(C.Structure):
    _fields_ = [("driver", C.c_char * 16), ("model", C.c_char * 32), ("serial", C.c_char * 40),
                ("bus_info", C.c_char * 32), ("media_version", C.c_uint32),
                ("hw_revision", C.c_uint32), ("driver_version", C.c_uint32),
                ("reserved", C.c_uint32 * 31)]


class MediaV2Entity(_Packed):
    _fields_ = [("id", C.c_uint32), ("name", C.c_char * 64), ("function", C.c_uint32),
                ("flags", C.c_uint32), ("reserved", C.c_uint32 * 5)]


class MediaV2IntfDevnode(_Packed):
    _fields_ = [("major", C.c_uint32), ("minor", C.c_uint32)]


class _IntfUnion(C.Union):
    _pack_ = 1
    _fields_ = [("devnode", MediaV2IntfDevnode), ("raw", C.c_uint32 * 16)]


class MediaV2Interface(_Packed):
    _fields_ = [("id", C.c_uint32), ("intf_type", C.c_uint32), ("flags", C.c_uint32),
                ("reserved", C.c_uint32 * 9), ("u", _IntfUnion)]


class MediaV2Pad(_Packed):
    _fields_ = [("id", C.c_uint32), ("entity_id", C.c_uint32), ("flags", C.c_uint32),
                ("index", C.c_uint32), ("reserved", C.c_uint32 * 4)]


class MediaV2Link(_Packed):
    _fields_ = [("id", C.c_uint32), ("source_id", C.c_uint32), ("sink_id", C.c_uint32),
                ("flags", C.c_uint32), ("reserved", C.c_uint32 * 6)]


class MediaV2Topology(_Packed):
    _fields_ = [("topology_version", C.c_uint64),
                ("num_entities", C.c_uint32), ("reserved1", C.c_uint32),
                ("ptr_entities", C.c_uint64),
                ("num_interfaces", C.c_uint32), ("reserved2", C.c_uint32),
                ("ptr_interfaces", C.c_uint64),
                ("num_pads", C.c_uint32), ("reserved3", C.c_uint32),
                ("ptr_pads", C.c_uint64),
                ("num_links", C.c_uint32), ("reserved4", C.c_uint32),
                ("ptr_links", C.c_uint64)]


class MediaPadDesc(C.Structure):
    _fields_ = [("entity", C.c_uint32), ("index", C.c_uint16), ("flags", C.c_uint32),
                ("reserved", C.c_uint32 * 2)]


class MediaLinkDesc(C.Structure):
    _fields_ = [("source", MediaPadDesc), ("sink", MediaPadDesc), ("flags", C.c_uint32),
                ("reserved", C.c_uint32 * 2)]


# ---- linux/v4l2-mediabus.h, linux/v4l2-subdev.h ------------------------------------


class MbusFramefmt(C.Structure):
    _fields_ = [("width", C.c_uint32), ("height", C.c_uint32), ("code", C.c_uint32),
                ("field", C.c_uint32), ("colorspace", C.c_uint32), ("ycbcr_enc", C.c_uint16),
                ("quantization", C.c_uint16), ("xfer_func", C.c_uint16),
                ("flags", C.c_uint16), ("reserved", C.c_uint16 * 10)]


class SubdevFormat(C.Structure):
    _fields_ = [("which", C.c_uint32), ("pad", C.c_uint32), ("format", MbusFramefmt),
                ("reserved", C.c_uint32 * 8)]


# ---- linux/videodev2.h -------------------------------------------------------------


class PixFormat(C.Structure):
    _fields_ = [("width", C.c_uint32), ("height", C.c_uint32), ("pixelformat", C.c_uint32),
                ("field", C.c_uint32), ("bytesperline", C.c_uint32),
                ("sizeimage", C.c_uint32), ("colorspace", C.c_uint32), ("priv", C.c_uint32),
                ("flags", C.c_uint32), ("ycbcr_enc", C.c_uint32),
                ("quantization", C.c_uint32), ("xfer_func", C.c_uint32)]


class _FormatUnion(C.Union):
    # raw_data[200] plus a pointer member: the union is 8-byte aligned on 64-bit,
    # as the kernel's (struct v4l2_window holds pointers).
    _fields_ = [("pix", PixFormat), ("raw_data", C.c_uint8 * 200), ("_align", C.c_void_p)]


class Format(C.Structure):
    _fields_ = [("type", C.c_uint32), ("fmt", _FormatUnion)]


class RequestBuffers(C.Structure):
    _fields_ = [("count", C.c_uint32), ("type", C.c_uint32), ("memory", C.c_uint32),
                ("capabilities", C.c_uint32), ("flags", C.c_uint8),
                ("reserved", C.c_uint8 * 3)]


class Timeval(C.Structure):
    _fields_ = [("tv_sec", C.c_long), ("tv_usec", C.c_long)]


class Timecode(C.Structure):
    _fields_ = [("type", C.c_uint32), ("flags", C.c_uint32), ("frames", C.c_uint8),
                ("seconds", C.c_uint8), ("minutes", C.c_uint8), ("hours", C.c_uint8),
                ("userbits", C.c_uint8 * 4)]


class _BufferM(C.Union):
    _fields_ = [("offset", C.c_uint32), ("userptr", C.c_ulong), ("planes", C.c_void_p),
                ("fd", C.c_int32)]


class Buffer(C.Structure):
    _fields_ = [("index", C.c_uint32), ("type", C.c_uint32), ("bytesused", C.c_uint32),
                ("flags", C.c_uint32), ("field", C.c_uint32), ("timestamp", Timeval),
                ("timecode", Timecode), ("sequence", C.c_uint32), ("memory", C.c_uint32),
                ("m", _BufferM), ("length", C.c_uint32), ("reserved2", C.c_uint32),
                ("request_fd", C.c_int32)]


class _ExtValue(C.Union):
    _pack_ = 1
    _fields_ = [("value", C.c_int32), ("value64", C.c_int64), ("ptr", C.c_void_p)]


class ExtControl(_Packed):
    _fields_ = [("id", C.c_uint32), ("size", C.c_uint32), ("reserved2", C.c_uint32),
                ("u", _ExtValue)]


class ExtControls(C.Structure):
    _fields_ = [("which", C.c_uint32), ("count", C.c_uint32), ("error_idx", C.c_uint32),
                ("request_fd", C.c_int32), ("reserved", C.c_uint32),
                ("controls", C.POINTER(ExtControl))]


class QueryCtrl(C.Structure):
    _fields_ = [("id", C.c_uint32), ("type", C.c_uint32), ("name", C.c_char * 32),
                ("minimum", C.c_int32), ("maximum", C.c_int32), ("step", C.c_int32),
                ("default_value", C.c_int32), ("flags", C.c_uint32),
                ("reserved", C.c_uint32 * 2)]


_RW = _IOC_READ | _IOC_WRITE
IOCTL = {
    "MEDIA_IOC_DEVICE_INFO": _ioc(_RW, "|", 0x00, MediaDeviceInfo),
    "MEDIA_IOC_SETUP_LINK": _ioc(_RW, "|", 0x03, MediaLinkDesc),
    "MEDIA_IOC_G_TOPOLOGY": _ioc(_RW, "|", 0x04, MediaV2Topology),
    "VIDIOC_SUBDEV_G_FMT": _ioc(_RW, "V", 4, SubdevFormat),
    "VIDIOC_SUBDEV_S_FMT": _ioc(_RW, "V", 5, SubdevFormat),
    "VIDIOC_G_FMT": _ioc(_RW, "V", 4, Format),
    "VIDIOC_S_FMT": _ioc(_RW, "V", 5, Format),
    "VIDIOC_REQBUFS": _ioc(_RW, "V", 8, RequestBuffers),
    "VIDIOC_QUERYBUF": _ioc(_RW, "V", 9, Buffer),
    "VIDIOC_QBUF": _ioc(_RW, "V", 15, Buffer),
    "VIDIOC_DQBUF": _ioc(_RW, "V", 17, Buffer),
    "VIDIOC_STREAMON": _ioc(_IOC_WRITE, "V", 18, C.c_int),
    "VIDIOC_STREAMOFF": _ioc(_IOC_WRITE, "V", 19, C.c_int),
    "VIDIOC_QUERYCTRL": _ioc(_RW, "V", 36, QueryCtrl),
    "VIDIOC_G_EXT_CTRLS": _ioc(_RW, "V", 71, ExtControls),
    "VIDIOC_S_EXT_CTRLS": _ioc(_RW, "V", 72, ExtControls),
}

CONST = {
    # media.h
    "MEDIA_ENT_F_IO_V4L": 0x00010001,
    "MEDIA_ENT_F_CAM_SENSOR": 0x00020001,
    "MEDIA_PAD_FL_SINK": 1 << 0,
    "MEDIA_PAD_FL_SOURCE": 1 << 1,
    "MEDIA_LNK_FL_ENABLED": 1 << 0,
    "MEDIA_LNK_FL_IMMUTABLE": 1 << 1,
    "MEDIA_LNK_FL_LINK_TYPE": 0xF << 28,
    "MEDIA_LNK_FL_DATA_LINK": 0 << 28,
    "MEDIA_LNK_FL_INTERFACE_LINK": 1 << 28,
    "MEDIA_INTF_T_V4L_VIDEO": 0x200,
    "MEDIA_INTF_T_V4L_SUBDEV": 0x203,
    # media-bus-format.h
    "MEDIA_BUS_FMT_Y8_1X8": 0x2001,
    "MEDIA_BUS_FMT_Y10_1X10": 0x200A,
    # videodev2.h
    "V4L2_PIX_FMT_GREY": fourcc("GREY"),
    "V4L2_PIX_FMT_Y10P": fourcc("Y10P"),
    "V4L2_PIX_FMT_Y16": fourcc("Y16 "),
    "V4L2_BUF_TYPE_VIDEO_CAPTURE": 1,
    "V4L2_MEMORY_MMAP": 1,
    "V4L2_FIELD_NONE": 1,
    "V4L2_COLORSPACE_RAW": 11,
    "V4L2_BUF_FLAG_ERROR": 0x40,
    "V4L2_BUF_FLAG_TIMESTAMP_MASK": 0xE000,
    "V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC": 0x2000,
    "V4L2_CTRL_WHICH_CUR_VAL": 0,
    # v4l2-subdev.h
    "V4L2_SUBDEV_FORMAT_ACTIVE": 1,
    # v4l2-controls.h
    "V4L2_CID_EXPOSURE": 0x00980911,
    "V4L2_CID_VBLANK": 0x009E0901,
    "V4L2_CID_HBLANK": 0x009E0902,
    "V4L2_CID_ANALOGUE_GAIN": 0x009E0903,
    "V4L2_CID_PIXEL_RATE": 0x009F0902,
}
