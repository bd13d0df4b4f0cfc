"""The crane side's C codec, built and driven from Python (import as ``tests.field.c_codec``).

``cantools generate_c_source`` turns a DBC into ``NAME.c`` / ``NAME.h`` (pack/unpack per message,
encode/decode/is_in_range per signal). :func:`build` compiles that code with ``gcc -Wall -Werror``
together with a small harness written here: the harness reads one request per line on stdin and
answers one line on stdout, so a whole batch of frames costs one process.

Requests (``KIND`` = DBC message name; values in DBC signal order, decimal):

- ``pack KIND RAW...``    -> frame hex (generated ``*_pack``, raw values, no protection)
- ``unpack KIND HEX``     -> ``RAW...`` (generated ``*_unpack``)
- ``encode KIND PHYS...`` -> frame hex: ``*_encode`` per signal, ``*_pack``, then the AUTOSAR E2E
  Profile 5 CRC computed in C and packed into the ``CRC`` signal by the generated code (the
  ``CRC`` value given is ignored)
- ``decode KIND HEX``     -> ``ok|crc PHYS...`` (E2E check in C, then ``*_unpack``, ``*_decode``)
- ``range KIND RAW...``   -> ``1|0`` per signal (generated ``*_is_in_range``)

A bad request answers ``error ...``. The E2E CRC is written once, here, in C: CRC-16/CCITT-FALSE
(polynomial 0x1021, initial value 0xFFFF) over the frame's bytes from byte 2 on, then over the
message's data ID, low byte first (what the ``autosar-e2e`` package computes for the laptop).
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: gcc flags: the issue's ``-Wall -Werror``, plus the stricter warnings an ECU build would use
GCC_FLAGS = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O1")

_E2E_AND_IO = r"""
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* AUTOSAR E2E Profile 5: CRC-16/CCITT-FALSE over bytes 2.. of the frame, then the data ID
   (low byte, high byte); the CRC lives in bytes 0-1 (the DBC's CRC signal). */
static uint16_t crc16_ccitt_false(const uint8_t *p, size_t n, uint16_t crc)
{
    size_t i;
    int b;

    for (i = 0; i < n; i++) {
        crc = (uint16_t)(crc ^ (uint16_t)(p[i] << 8));
        for (b = 0; b < 8; b++) {
            crc = (crc & 0x8000u) ? (uint16_t)((crc << 1) ^ 0x1021u) : (uint16_t)(crc << 1);
        }
    }
    return crc;
}

static uint16_t e2e_p05_crc(const uint8_t *frame, size_t length, uint16_t data_id)
{
    const uint8_t id[2] = {(uint8_t)(data_id & 0xFFu), (uint8_t)(data_id >> 8)};

    return crc16_ccitt_false(id, 2, crc16_ccitt_false(frame + 2, length - 2, 0xFFFFu));
}

static void put_hex(const uint8_t *buf, size_t n)
{
    size_t i;

    for (i = 0; i < n; i++) {
        printf("%02x", buf[i]);
    }
    printf("\n");
}

/* hex text -> bytes; the number of bytes, or -1 */
static int from_hex(const char *text, uint8_t *buf, size_t size)
{
    size_t n = strlen(text), i;

    if (n % 2 != 0 || n / 2 > size) {
        return -1;
    }
    for (i = 0; i < n / 2; i++) {
        unsigned int byte;
        if (sscanf(text + 2 * i, "%2x", &byte) != 1) {
            return -1;
        }
        buf[i] = (uint8_t)byte;
    }
    return (int)(n / 2);
}

static int64_t parse_signed(const char *text)
{
    return (int64_t)strtoll(text, NULL, 10);
}

static uint64_t parse_unsigned(const char *text)
{
    return (uint64_t)strtoull(text, NULL, 10);
}
"""


@dataclass(frozen=True)
class CSignal:
    name: str  # DBC signal name
    member: str  # C struct member (and function infix)
    ctype: str  # C type of the raw value, e.g. int64_t

    @property
    def signed(self) -> bool:
        return not self.ctype.startswith("u")


@dataclass(frozen=True)
class CMessage:
    name: str  # DBC message name
    prefix: str  # C prefix, e.g. loggrasp_grasp_command
    length: int  # frame bytes
    data_id: int  # E2EDataID attribute; -1: no E2E header (a signature frame)
    signals: tuple[CSignal, ...]  # DBC order


def generate_c(dbc: Path, out_dir: Path) -> tuple[Path, Path]:
    """Run ``cantools generate_c_source`` on ``dbc``; returns the ``.c`` and ``.h`` it wrote."""
    out_dir.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "cantools", "generate_c_source", "-o", str(out_dir), str(dbc)],
                   check=True, capture_output=True, text=True)
    return out_dir / f"{dbc.stem}.c", out_dir / f"{dbc.stem}.h"


def read_header(header: Path, db: Any) -> list[CMessage]:
    """Every message of ``db`` as the generated header declares it: the struct members in DBC
    signal order, each checked against its ``*_NAME`` macro."""
    text = header.read_text()
    messages = []
    for message in db.messages:
        macro = re.search(rf"#define (\w+)_NAME \"{message.name}\"", text).group(1)
        prefix = macro.lower()
        body = re.search(rf"struct {prefix}_t {{(.*?)\n}};", text, re.S).group(1)
        members = re.findall(r"^    (\w+) (\w+);$", body, re.M)
        if len(members) != len(message.signals):
            raise RuntimeError(f"{header}: struct {prefix}_t has {len(members)} members, the DBC "
                               f"{len(message.signals)} signals")
        signals = []
        for sig, (ctype, member) in zip(message.signals, members):
            if f'#define {macro}_{member.upper()}_NAME "{sig.name}"' not in text:
                raise RuntimeError(f"{header}: {prefix}_t.{member} is not signal {sig.name}")
            signals.append(CSignal(sig.name, member, ctype))
        e2e = message.dbc.attributes.get("E2EDataID")  # none: a signature frame (no E2E header)
        data_id = int(e2e.value) if e2e is not None else -1
        messages.append(CMessage(message.name, prefix, message.length, data_id, tuple(signals)))
    return messages


def _message_source(m: CMessage) -> str:
    """The harness's request handler for one message."""
    t, n, upper = f"struct {m.prefix}_t", len(m.signals), m.prefix.upper()
    fill, show_raw, show_phys, ranges = [], [], [], []
    for s in m.signals:
        f = f"{m.prefix}_{s.member}"
        raw = f"({s.ctype})parse_{'signed' if s.signed else 'unsigned'}(tok[{len(fill)}])"
        fill.append(f"    msg->{s.member} = phys ? {f}_encode(strtod(tok[{len(fill)}], NULL)) : {raw};")
        fmt, cast = ("%lld", "long long") if s.signed else ("%llu", "unsigned long long")
        show_raw.append(f'    printf(" {fmt}", ({cast})msg->{s.member});')
        show_phys.append(f'    printf(" %.17g", {f}_decode(msg->{s.member}));')
        ranges.append(f'    printf(" %d", {f}_is_in_range({raw}) ? 1 : 0);')
    crc = next((s.member for s in m.signals if s.name == "CRC"), None)
    check = f'msg->{crc} == e2e_p05_crc(buf, sizeof(buf), {m.data_id}u) ? "ok" : "crc"' if crc else '"ok"'
    protect = (f"""    if (n >= 0 && op[0] == 'e') {{
        msg->{crc} = e2e_p05_crc(buf, (size_t)n, {m.data_id}u);
        n = {m.prefix}_pack(buf, msg, sizeof(buf));
    }}
""" if crc else "")
    nl = "\n"
    return f"""
static void fill_{m.prefix}({t} *msg, char **tok, int phys)
{{
{nl.join(fill)}
}}

static void run_{m.prefix}(const char *op, char **tok, int ntok)
{{
    {t} msg_, *msg = &msg_;
    uint8_t buf[{upper}_LENGTH];
    int n;

    memset(msg, 0, sizeof(*msg));
    if (strcmp(op, "unpack") == 0 || strcmp(op, "decode") == 0) {{
        if (ntok != 1 || from_hex(tok[0], buf, sizeof(buf)) != {upper}_LENGTH) {{
            printf("error hex\\n");
            return;
        }}
        if ({m.prefix}_unpack(msg, buf, sizeof(buf)) != 0) {{
            printf("error unpack\\n");
            return;
        }}
        if (op[0] == 'u') {{
            printf("raw");
{nl.join("    " + x for x in show_raw)}
        }} else {{
            printf("%s", {check});
{nl.join("    " + x for x in show_phys)}
        }}
        printf("\\n");
        return;
    }}
    if (ntok != {n}) {{
        printf("error arity\\n");
        return;
    }}
    if (strcmp(op, "range") == 0) {{
        printf("range");
{nl.join(ranges)}
        printf("\\n");
        return;
    }}
    if (strcmp(op, "pack") != 0 && strcmp(op, "encode") != 0) {{
        printf("error op\\n");
        return;
    }}
    fill_{m.prefix}(msg, tok, op[0] == 'e');
    n = {m.prefix}_pack(buf, msg, sizeof(buf));
{protect}    if (n != {upper}_LENGTH) {{
        printf("error pack %d\\n", n);
        return;
    }}
    put_hex(buf, (size_t)n);
}}
"""


def harness_source(header_name: str, messages: list[CMessage]) -> str:
    """The whole harness: E2E and I/O helpers, one handler per message, the request loop."""
    dispatch = "\n        ".join(f'else if (strcmp(kind, "{m.name}") == 0) run_{m.prefix}(op, tok, ntok);'
                                for m in messages)
    return (f'#include "{header_name}"\n' + _E2E_AND_IO + "".join(_message_source(m) for m in messages) + f"""
int main(void)
{{
    static char line[16384];
    char *tok[64], *op, *kind, *t;
    int ntok;

    while (fgets(line, sizeof(line), stdin) != NULL) {{
        op = strtok(line, " \\n");
        kind = strtok(NULL, " \\n");
        ntok = 0;
        while (ntok < 64 && (t = strtok(NULL, " \\n")) != NULL) {{
            tok[ntok++] = t;
        }}
        if (op == NULL || kind == NULL) printf("error request\\n");
        {dispatch}
        else printf("error kind\\n");
    }}
    return 0;
}}
""")


class CHarness:
    """The compiled harness; :meth:`ask` sends a batch of requests to one process."""

    def __init__(self, exe: Path, messages: list[CMessage]) -> None:
        self.exe = exe
        self.messages = {m.name: m for m in messages}

    def ask(self, requests: list[str]) -> list[str]:
        done = subprocess.run([str(self.exe)], input="".join(r + "\n" for r in requests), capture_output=True,
                              text=True, timeout=120, check=True)
        answers = done.stdout.splitlines()
        if len(answers) != len(requests):
            raise RuntimeError(f"C harness answered {len(answers)} lines to {len(requests)} requests: {done.stderr}")
        return answers


def build(dbc: Path, db: Any, work: Path) -> CHarness:
    """Generate C from ``dbc`` (parsed as ``db``) into ``work``, compile it with the harness."""
    gcc = shutil.which("gcc")
    if gcc is None:
        raise RuntimeError("gcc not found: the crane-side codec test needs it; run scripts/setup.sh "
                           "(it installs Debian's gcc and libc6-dev)")
    source, header = generate_c(dbc, work)
    messages = read_header(header, db)
    harness = work / "harness.c"
    harness.write_text(harness_source(header.name, messages))
    exe = work / "harness"
    done = subprocess.run([gcc, *GCC_FLAGS, str(source), str(harness), "-o", str(exe)], capture_output=True,
                          text=True)
    if done.returncode != 0:
        raise RuntimeError(f"gcc {' '.join(GCC_FLAGS)} failed on the generated code:\n{done.stderr}")
    return CHarness(exe, messages)
