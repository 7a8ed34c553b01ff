"""A second decoder, written from docs/protocol.md alone (it imports nothing from tracker).

Used by tests to check that what the tracker sends is what the ICD says, byte
for byte. Layouts are transcribed from the ICD's section 5 tables.
"""

import struct

ASM = bytes([0x1A, 0xCF, 0xFC, 0x1D])

# ICD section 5: (id, struct of the fixed part, names), items for CENTROIDS.
LAYOUTS = {
    0x001: (">IQfffffffffHBH", "frame_id t_ns q_w q_x q_y q_z sigma_cross_arcsec "
            "sigma_roll_arcsec rate_x rate_y rate_z matched mode flags"),
    0x002: (">IQBBHB", "frame_id t_ns part parts total count"),
    0x003: (">IfIffBIIIIHIHIBBf", "uptime_s frame_rate_hz exposure_us gain cpu_temp_c mode "
            "frames capture_faults solve_failures link_drops link_reopens rx_rejects "
            "last_error config_crc time_source corrections psf_fwhm_px"),
    0x010: (">HHBQ", "cmd_id cmd_seq code rx_t_ns"),
    0x011: (">HHBQ", "cmd_id cmd_seq code rx_t_ns"),
}
CENTROID_ITEM = (">fffIH", "x y flux hip flags")


def crc_ccitt_false(data: bytes) -> int:
    """Bit by bit: poly 0x1021, init 0xFFFF, MSB first, no final XOR (ICD section 3)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


def decode_telemetry(stream: bytes) -> list[dict]:
    """Every intact telemetry frame in stream (ICD section 3.1), decoded by section 5."""
    out = []
    i = 0
    while True:
        i = stream.find(ASM, i)
        if i < 0 or len(stream) - i < 10:
            return out
        w0, w1, w2 = struct.unpack_from(">HHH", stream, i + 4)
        version, ptype, sec = w0 >> 13, (w0 >> 12) & 1, (w0 >> 11) & 1
        n = w2 + 1 - 2
        if version or ptype or sec or (w1 >> 14) != 3 or not 0 <= n <= 737:
            i += 1
            continue
        end = i + 12 + n
        if end > len(stream):
            return out
        crc = struct.unpack_from(">H", stream, end - 2)[0]
        if crc_ccitt_false(stream[i + 4:end - 2]) != crc:
            i += 1
            continue
        apid, payload = w0 & 0x7FF, stream[i + 10:end - 2]
        rec = {"apid": apid, "seq": w1 & 0x3FFF, "payload": payload}
        fmt, names = LAYOUTS[apid]
        rec["values"] = dict(zip(names.split(), struct.unpack_from(fmt, payload), strict=True))
        if apid == 0x002:
            size = struct.calcsize(fmt)
            ifmt, inames = CENTROID_ITEM
            isize = struct.calcsize(ifmt)
            assert len(payload) == size + isize * rec["values"]["count"]
            rec["items"] = [dict(zip(inames.split(), struct.unpack_from(ifmt, payload,
                                                                        size + k * isize),
                                     strict=True))
                            for k in range(rec["values"]["count"])]
        else:
            assert len(payload) == struct.calcsize(fmt)
        out.append(rec)
        i = end
