"""Render the ICD's tables and the FC's C header from the message table.

``python -m tracker.protocol.docgen`` rewrites the generated sections of
docs/protocol.md (between ``<!-- generated:NAME -->`` and
``<!-- end:NAME -->``) and tools/fc/st_protocol.h; ``--check`` only reports
whether they are up to date (exit 1 if not). A test runs the check.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from tracker.protocol.budget import (
    bytes_per_second,
    centroids_bytes,
    load_bytes_per_second,
    packet_bytes,
)
from tracker.protocol.framing import OVERHEAD
from tracker.protocol.messages import (
    ERROR_MEANING,
    MAX_STARS_PER_PACKET,
    MESSAGES,
    TYPES,
    AttitudeFlag,
    Correction,
    Direction,
    ErrorCode,
    MessageDef,
    Mode,
    MsgId,
    Reason,
    TimeSource,
)

__all__ = ["render_sections", "render_c_header", "apply_sections"]

ROOT = Path(__file__).resolve().parents[2]
ICD_PATH = ROOT / "docs" / "protocol.md"
HEADER_PATH = ROOT / "tools" / "fc" / "st_protocol.h"
BAUDS = (115200, 921600)
FRACTION = 0.9   # the shipped LinkConfig.bandwidth_fraction


def _field_rows(fields, start: int = 0) -> list[str]:
    rows, off = [], start
    for f in fields:
        rows.append(f"| {off} | `{f.name}` | {f.type} | {f.unit or '-'} | "
                    f"{f.range_text() or '-'} | {f.doc} |")
        off += TYPES[f.type][1]
    return rows


def _message_section(m: MessageDef) -> list[str]:
    lines = [f"### 0x{m.id:03X} {m.name} ({m.direction.name})", "", m.doc[0].upper() + m.doc[1:]
             + ".", ""]
    if not m.fields:
        return lines + ["Empty payload (0 bytes).", ""]
    lines += ["| offset | field | type | unit | valid | meaning |",
              "|---:|---|---|---|---|---|", *_field_rows(m.fields), ""]
    if m.item:
        lines += [f"Then `{m.count_field}` items (0 .. {m.max_items}) of {m.item_size} bytes "
                  f"each; item k starts at payload offset {m.min_size} + {m.item_size} k:", "",
                  "| offset in item | field | type | unit | valid | meaning |",
                  "|---:|---|---|---|---|---|", *_field_rows(m.item), "",
                  f"Payload: {m.min_size} + {m.item_size} x count bytes "
                  f"({m.min_size} .. {m.max_size}).", ""]
    else:
        lines += [f"Payload: {m.min_size} bytes; packet: {m.min_size + OVERHEAD} bytes.", ""]
    return lines


def _ids() -> str:
    rows = ["| id (APID) | name | dir | payload bytes | packet bytes | queue class |",
            "|---|---|---|---:|---:|---|"]
    for m in MESSAGES:
        size = (f"{m.min_size}" if not m.item else f"{m.min_size} .. {m.max_size}")
        packet = (f"{m.min_size + OVERHEAD}" if not m.item
                  else f"{m.min_size + OVERHEAD} .. {m.max_size + OVERHEAD}")
        pri = "-" if m.priority is None else str(m.priority)
        rows.append(f"| 0x{m.id:03X} | {m.name} | {m.direction.name} | {size} | {packet} | "
                    f"{pri} |")
    return "\n".join(rows)


def _bits(flag) -> list:
    """The single-bit members of an IntFlag (not its 0-valued NONE)."""
    return [e for e in flag.__members__.values() if int(e)]


def _enums() -> str:
    out = []
    for title, enum in (("Mode", Mode), ("Reason (ACK/NACK `code`)", Reason),
                        ("AttitudeFlag (bits of ATTITUDE `flags`; other bits are 0)",
                         AttitudeFlag), ("TimeSource (STATUS `time_source`)", TimeSource),
                        ("Correction (bits of STATUS `corrections`; other bits are 0)",
                         _bits(Correction))):
        out += [f"**{title}**", "", "| value | name |", "|---:|---|"]
        out += [f"| {int(e)} | {e.name} |" for e in enum]
        out.append("")
    out += ["**ErrorCode (STATUS `last_error`)**", "", "| value | name | meaning |",
            "|---:|---|---|"]
    out += [f"| {int(e)} | {e.name} | {ERROR_MEANING[e]} |" for e in ErrorCode]
    return "\n".join(out)


def _budget() -> str:
    att, st = packet_bytes(MsgId.ATTITUDE), packet_bytes(MsgId.STATUS)
    rows = [f"Usable bytes per second = baud / 10 (8N1) x {FRACTION} (bandwidth_fraction). "
            f"ATTITUDE packet {att} B, STATUS {st} B, CENTROIDS for n stars "
            f"= {packet_bytes(MsgId.CENTROIDS)} B per part of up to {MAX_STARS_PER_PACKET} "
            f"+ {packet_bytes(MsgId.CENTROIDS, 1) - packet_bytes(MsgId.CENTROIDS)} B per star "
            f"(48 stars: {centroids_bytes(48)} B).", "",
            "| baud | usable B/s | ATTITUDE alone, max Hz | CENTROIDS 48 stars alone, max Hz "
            "| ATT 30 Hz + STATUS 1 Hz + CENTROIDS 48 stars at | load |",
            "|---:|---:|---:|---:|---|---:|"]
    for baud in BAUDS:
        usable = bytes_per_second(baud) * FRACTION
        for cen_hz in (1.0, 10.0, 30.0):
            load = load_bytes_per_second(30.0, cen_hz, 1.0, 48)
            rows.append(f"| {baud} | {usable:.0f} | {usable / att:.0f} | "
                        f"{usable / centroids_bytes(48):.1f} | {cen_hz:g} Hz | "
                        f"{100 * load / usable:.0f} % |")
    return "\n".join(rows)


def render_sections() -> dict[str, str]:
    """Generated Markdown for each named section of docs/protocol.md."""
    msgs = []
    for m in MESSAGES:
        msgs += _message_section(m)
    return {"ids": _ids(), "messages": "\n".join(msgs).rstrip(), "enums": _enums(),
            "budget": _budget()}


def apply_sections(text: str, sections: dict[str, str]) -> str:
    """text with each ``<!-- generated:NAME -->...<!-- end:NAME -->`` block refilled."""
    for name, body in sections.items():
        pat = re.compile(rf"(<!-- generated:{name} -->\n).*?(<!-- end:{name} -->)", re.S)
        if not pat.search(text):
            raise ValueError(f"docs/protocol.md has no generated:{name} block")
        text = pat.sub(lambda mo, b=body: mo.group(1) + b + "\n" + mo.group(2), text)
    return text


# ---- C header --------------------------------------------------------------------


def _c_name(m: MessageDef) -> str:
    return m.name.lower()


def _c_struct(m: MessageDef) -> list[str]:
    n = _c_name(m)
    out = []
    if m.item:
        out += ["typedef struct {"] + [f"    {TYPES[f.type][2]} {f.name}; /* {f.unit or '-'}: "
                                       f"{f.doc} */" for f in m.item]
        out += [f"}} st_{n}_item_t;", ""]
    out += ["typedef struct {"]
    out += [f"    {TYPES[f.type][2]} {f.name}; /* {f.unit or '-'}: {f.doc} */" for f in m.fields]
    if m.item:
        out.append(f"    st_{n}_item_t items[{m.max_items}];")
    if not m.fields:
        out.append("    uint8_t unused; /* empty payload */")
    out += [f"}} st_{n}_t;", ""]
    return out


def _c_parse(m: MessageDef) -> list[str]:
    n = _c_name(m)
    out = ["/* Payload -> struct. Returns ST_OK, ST_WRONG_LENGTH or ST_OUT_OF_RANGE. */",
           f"static inline int st_parse_{n}(const uint8_t *p, size_t n, st_{n}_t *m)", "{"]
    off = 0
    if m.item:
        out.append("    size_t k;")
        out.append(f"    if (n < {m.min_size}u) return ST_WRONG_LENGTH;")
    else:
        out.append(f"    if (n != {m.min_size}u) return ST_WRONG_LENGTH;")
    if not m.fields:
        out += ["    (void)p;", "    m->unused = 0;"]
    for f in m.fields:
        out.append(f"    m->{f.name} = st_get_{f.type}(p + {off});")
        off += TYPES[f.type][1]
    if m.item:
        out += [f"    if (m->{m.count_field} > {m.max_items}u) return ST_OUT_OF_RANGE;",
                f"    if (n != {m.min_size}u + {m.item_size}u * (size_t)m->{m.count_field}) "
                "return ST_WRONG_LENGTH;",
                f"    for (k = 0; k < m->{m.count_field}; k++) {{",
                f"        const uint8_t *q = p + {m.min_size}u + {m.item_size}u * k;"]
        ioff = 0
        for f in m.item:
            out.append(f"        m->items[k].{f.name} = st_get_{f.type}(q + {ioff});")
            ioff += TYPES[f.type][1]
        out.append("    }")
    for f in m.fields:
        cond = _c_range_check(f)
        if cond:
            out.append(f"    if ({cond}) return ST_OUT_OF_RANGE;")
    return out + ["    return ST_OK;", "}", ""]


def _c_literal(f, value) -> str:
    if f.type == "f32":
        return f"{float(value)!r}f"
    return f"{int(value)}ull" if f.type == "u64" else f"{int(value)}u"


def _c_range_check(f) -> str:
    """The C condition that is true when field f of struct m is NOT valid ('' if any is)."""
    if f.choices is not None:
        return " && ".join(f"m->{f.name} != {c}u" for c in f.choices)
    if f.lo is None:
        return ""
    inside = [f"m->{f.name} <= {_c_literal(f, f.hi)}"]
    if f.type == "f32" or f.lo > 0:         # an unsigned field is never below 0
        inside.insert(0, f"m->{f.name} >= {_c_literal(f, f.lo)}")
    ok = " && ".join(inside)
    if f.also:
        ok = " || ".join([*(f"m->{f.name} == {_c_literal(f, a)}" for a in f.also), f"({ok})"])
    return f"!({ok})"


def _c_pack(m: MessageDef) -> list[str]:
    n = _c_name(m)
    out = [f"/* Struct -> payload (p must hold {m.min_size} bytes). Returns the length. */",
           f"static inline size_t st_pack_{n}(uint8_t *p, const st_{n}_t *m)", "{"]
    if not m.fields:
        out += ["    (void)p;", "    (void)m;"]
    off = 0
    for f in m.fields:
        out.append(f"    st_put_{f.type}(p + {off}, m->{f.name});")
        off += TYPES[f.type][1]
    return out + [f"    return {m.min_size}u;", "}", ""]


_C_HELPERS = """\
static inline uint8_t st_get_u8(const uint8_t *p) { return p[0]; }
static inline uint16_t st_get_u16(const uint8_t *p)
{
    return (uint16_t)((p[0] << 8) | p[1]);
}
static inline uint32_t st_get_u32(const uint8_t *p)
{
    return ((uint32_t)p[0] << 24) | ((uint32_t)p[1] << 16) | ((uint32_t)p[2] << 8) | p[3];
}
static inline uint64_t st_get_u64(const uint8_t *p)
{
    return ((uint64_t)st_get_u32(p) << 32) | st_get_u32(p + 4);
}
static inline float st_get_f32(const uint8_t *p)
{
    uint32_t u = st_get_u32(p);
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}
static inline void st_put_u8(uint8_t *p, uint8_t v) { p[0] = v; }
static inline void st_put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)(v >> 8);
    p[1] = (uint8_t)v;
}
static inline void st_put_u32(uint8_t *p, uint32_t v)
{
    st_put_u16(p, (uint16_t)(v >> 16));
    st_put_u16(p + 2, (uint16_t)v);
}
static inline void st_put_u64(uint8_t *p, uint64_t v)
{
    st_put_u32(p, (uint32_t)(v >> 32));
    st_put_u32(p + 4, (uint32_t)v);
}
static inline void st_put_f32(uint8_t *p, float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    st_put_u32(p, u);
}
"""


_C_FMT = {"u8": ("%u", "unsigned"), "u16": ("%u", "unsigned"),
          "u32": ("%lu", "unsigned long"), "u64": ("%llu", "unsigned long long"),
          "f32": ("%.9g", "double")}


def _c_print(m: MessageDef) -> list[str]:
    n = _c_name(m)
    out = [f"static inline void st_print_{n}(FILE *f, const st_{n}_t *m)", "{"]
    if not m.fields:
        out.append("    (void)f; (void)m;")
    for fl in m.fields:
        fmt, cast = _C_FMT[fl.type]
        out.append(f'    fprintf(f, " {fl.name}={fmt}", ({cast})m->{fl.name});')
    if m.item:
        out += ["    {", "        unsigned k;",
                f"        for (k = 0; k < m->{m.count_field}; k++) {{"]
        for fl in m.item:
            fmt, cast = _C_FMT[fl.type]
            out.append(f'            fprintf(f, " {fl.name}[%u]={fmt}", k, '
                       f'({cast})m->items[k].{fl.name});')
        out += ["        }", "    }"]
    return out + ["}", ""]


def _c_print_any() -> list[str]:
    out = ["/* Parse a payload of message apid and print `NAME field=value ...` (no newline).",
           " * Returns ST_OK, ST_UNKNOWN_ID, ST_WRONG_LENGTH or ST_OUT_OF_RANGE. */",
           "static inline int st_print_payload(FILE *f, unsigned apid, const uint8_t *p, "
           "size_t n)", "{", "    int rc;", "    switch (apid) {"]
    for m in MESSAGES:
        nm = _c_name(m)
        out += [f"    case ST_ID_{m.name}: {{", f"        st_{nm}_t m;",
                f"        rc = st_parse_{nm}(p, n, &m);",
                f'        if (rc == ST_OK) {{ fprintf(f, "{m.name}"); st_print_{nm}(f, &m); }}',
                "        return rc;", "    }"]
    return out + ["    default:", "        return ST_UNKNOWN_ID;", "    }", "}", ""]


def render_c_header() -> str:
    """tools/fc/st_protocol.h: ids, enums, structs, parse/pack functions (C99)."""
    tm = max(m.max_size for m in MESSAGES if m.direction == Direction.TM)
    tc = max(m.max_size for m in MESSAGES if m.direction == Direction.TC)
    out = ["/* st_protocol.h: star tracker serial protocol, message layer (C99).",
           " *",
           " * GENERATED by `python -m tracker.protocol.docgen` from",
           " * tracker/protocol/messages.py; do not edit. See docs/protocol.md.",
           " * Framing and the streaming decoder are in st_decoder.h / st_decoder.c.",
           " */",
           "#ifndef ST_PROTOCOL_H", "#define ST_PROTOCOL_H", "",
           "#include <stddef.h>", "#include <stdint.h>", "#include <string.h>", "",
           "#define ST_ASM 0x1ACFFC1Du",
           f"#define ST_OVERHEAD {OVERHEAD}u /* ASM 4 + header 6 + CRC 2 */",
           f"#define ST_MAX_PAYLOAD_TM {tm}u", f"#define ST_MAX_PAYLOAD_TC {tc}u",
           f"#define ST_MAX_STARS_PER_PACKET {MAX_STARS_PER_PACKET}u", "",
           "enum st_msg_id {"]
    out += [f"    ST_ID_{m.name} = 0x{m.id:03X}, /* {m.direction.name} */" for m in MESSAGES]
    out += ["};", "", "enum st_mode {"]
    out += [f"    ST_MODE_{e.name} = {int(e)}," for e in Mode]
    out += ["};", "", "/* ACK/NACK codes; also what st_parse_* return. */", "enum st_reason {"]
    out += [f"    ST_{e.name} = {int(e)}," for e in Reason]
    out += ["};", "", "enum st_attitude_flag {"]
    out += [f"    ST_ATT_{e.name} = {int(e)}," for e in AttitudeFlag]
    out += ["};", "", "/* STATUS.time_source: where the frames' absolute time comes from. */",
            "enum st_time_source {"]
    out += [f"    ST_TIME_{e.name} = {int(e)}," for e in TimeSource]
    out += ["};", "", "/* Bits of STATUS.corrections: what the solver corrects. */",
            "enum st_correction {"]
    out += [f"    ST_CORR_{e.name} = {int(e)}," for e in _bits(Correction)]
    out += ["};", "", "/* STATUS.last_error: the latest fault the tracker survived. */",
            "enum st_error_code {"]
    out += [f"    ST_ERR_{e.name} = {int(e)}, /* {ERROR_MEANING[e]} */" for e in ErrorCode]
    out += ["};", ""]
    for m in MESSAGES:
        out.append(f"#define ST_{m.name}_SIZE {m.min_size}u")
        if m.item:
            out.append(f"#define ST_{m.name}_ITEM_SIZE {m.item_size}u")
    out += ["", _C_HELPERS]
    for m in MESSAGES:
        out += _c_struct(m)
    for m in MESSAGES:
        out += _c_parse(m)
        if m.direction == Direction.TC:
            out += _c_pack(m)
    out += ["#ifdef ST_WANT_PRINT /* optional text output, for tools and tests */",
            "#include <stdio.h>", ""]
    for m in MESSAGES:
        out += _c_print(m)
    out += _c_print_any()
    out += ["#endif /* ST_WANT_PRINT */", "", "#endif /* ST_PROTOCOL_H */", ""]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="only check; exit 1 if stale")
    args = ap.parse_args(argv)
    targets = {ICD_PATH: apply_sections(ICD_PATH.read_text(encoding="utf-8"),
                                        render_sections()),
               HEADER_PATH: render_c_header()}
    stale = [p for p, text in targets.items()
             if not p.exists() or p.read_text(encoding="utf-8") != text]
    for p in stale:
        if args.check:
            print(f"{p}: out of date; run python -m tracker.protocol.docgen", file=sys.stderr)
        else:
            p.write_text(targets[p], encoding="utf-8")
    return 1 if (args.check and stale) else 0


if __name__ == "__main__":
    sys.exit(main())
