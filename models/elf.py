"""Is a file a shared library this interpreter can open? A check of its ELF header and tables.

``dlopen`` trusts the file it is given: a truncated library, or one whose tables point past its
end, can kill the process (SIGBUS, SIGSEGV) before any error is raised. `check_shared_library`
reads only the file's headers, as ``struct`` records, and says what is wrong, before anything is
mapped:

- the ELF identification (magic number, 32/64 bits, byte order, version) and the machine equal
  the running interpreter's own, and the file is a shared object (``ET_DYN``);
- the program header table and the section header table lie inside the file, and so does
  every segment's file image (``PT_LOAD``, ``PT_DYNAMIC``, whose file size does not exceed its
  memory size) and every section's contents (all but ``SHT_NOBITS``);
- there is a loadable segment and a dynamic segment (what ``dlopen`` needs).

It cannot see machine code or constants that were overwritten in place (the tables are intact):
`models.compile` compares each cached library with the size and SHA-256 recorded when it was built
for that. On a system whose interpreter is not an ELF file (macOS, Windows) there is nothing to
compare with, and the check passes.
"""

from __future__ import annotations

import functools
import os
import struct
import sys
from dataclasses import dataclass

#: ELF constants (the System V ABI).
MAGIC = b"\x7fELF"
ET_DYN = 3
PT_LOAD, PT_DYNAMIC = 1, 2
SHT_NOBITS = 8
SHN_XINDEX = 0xFFFF


@dataclass(frozen=True)
class Layout:
    """The ``struct`` formats of one ELF class (byte order apart) and the sizes they describe.

    Attributes
    ----------
    header, header_size : the file header's fields after e_ident; its size in bytes (e_ident included)
    program, program_size, program_fields : a program header's fields, its size (bytes), and the indices
        of its type, file offset, file size and memory size
    section, section_size, section_fields : a section header's fields, its size (bytes), and the indices
        of its type, file offset and size (its link is field 6 in both classes)
    """

    header: str
    header_size: int
    program: str
    program_size: int
    program_fields: tuple[int, int, int, int]
    section: str
    section_size: int
    section_fields: tuple[int, int, int]


#: Per ELF class: 1 (32-bit), 2 (64-bit).
LAYOUTS = {
    1: Layout("HHIIIIIHHHHHH", 52, "IIIIIIII", 32, (0, 1, 4, 5), "IIIIIIIIII", 40, (1, 4, 5)),
    2: Layout("HHIQQQIHHHHHH", 64, "IIQQQQQQ", 56, (0, 2, 5, 6), "IIQQQQIIQQ", 64, (1, 4, 5)),
}


@functools.lru_cache(maxsize=1)
def host_identity() -> tuple[int, int, int] | None:
    """(class, byte order, machine) of the running interpreter's ELF file, or None when it is not one."""
    try:
        with open(os.path.realpath(sys.executable), "rb") as handle:
            head = handle.read(20)
    except OSError:
        return None
    if len(head) < 20 or head[:4] != MAGIC or head[4] not in LAYOUTS or head[5] not in (1, 2):
        return None
    order = "<" if head[5] == 1 else ">"
    return head[4], head[5], struct.unpack(order + "H", head[18:20])[0]


def check_shared_library(path: str | os.PathLike) -> str | None:
    """What makes the file at `path` unfit for ``dlopen`` here, in words; None when its headers hold.

    Parameters
    ----------
    path : the file (read, never mapped or executed)

    Returns
    -------
    str or None
        The first problem `check_image` finds, "cannot read it: ..." for an unreadable file, or None.
    """
    try:
        with open(path, "rb") as handle:
            data = handle.read()
    except OSError as err:
        return f"cannot read it: {err.strerror or err}"
    return check_image(data)


def check_image(data: bytes) -> str | None:
    """What makes the bytes `data` of a file unfit for ``dlopen`` here, in words; None when its headers hold.

    Parameters
    ----------
    data : the whole file

    Returns
    -------
    str or None
        The first problem found (too short, not ELF, another machine, not a shared object, a table or
        a segment beyond the end of the file, no loadable or dynamic segment), or None; always None
        where the interpreter itself is not an ELF file.
    """
    host = host_identity()
    if host is None:
        return None
    size = len(data)
    if size < 64 or data[:4] != MAGIC:
        return f"not an ELF file ({size} bytes{', no ELF magic number' if size >= 4 else ''})"
    elf_class, order_code, machine = host
    if data[4] != elf_class or data[5] != order_code or data[6] != 1:
        return f"ELF class {data[4]}, byte order {data[5]}, version {data[6]}: not this interpreter's"
    layout = LAYOUTS[elf_class]
    order = "<" if order_code == 1 else ">"
    (e_type, e_machine, _, _, phoff, shoff, _, ehsize, phentsize, phnum, shentsize, shnum, shstrndx) = (
        struct.unpack_from(order + layout.header, data, 16)
    )
    if e_type != ET_DYN:
        return f"ELF type {e_type}, not a shared object ({ET_DYN})"
    if e_machine != machine:
        return f"built for machine {e_machine}, this interpreter runs on machine {machine}"
    if ehsize != layout.header_size:
        return f"header size {ehsize}, expected {layout.header_size}"
    problem = _segments(data, order, layout, phoff, phentsize, phnum)
    return problem or _sections(data, order, layout, shoff, shentsize, shnum, shstrndx)


def _segments(data: bytes, order: str, layout: Layout, offset: int, entry: int, count: int) -> str | None:
    """What is wrong with the program header table (at `offset`, `count` entries of `entry` bytes), or None."""
    fields, expected, (kind, start, filesz, memsz) = layout.program, layout.program_size, layout.program_fields
    if count == 0:
        return "no program header table: nothing to load"
    if entry != expected:
        return f"program header size {entry}, expected {expected}"
    if offset + count * entry > len(data):
        return f"the program header table ends at byte {offset + count * entry}, beyond the file's {len(data)}"
    kinds = set()
    for k in range(count):
        header = struct.unpack_from(order + fields, data, offset + k * entry)
        kinds.add(header[kind])
        if header[kind] in (PT_LOAD, PT_DYNAMIC):
            if header[start] + header[filesz] > len(data):
                return f"segment {k} ends at byte {header[start] + header[filesz]}, beyond the file's {len(data)}"
            if header[filesz] > header[memsz]:
                return f"segment {k} has more bytes in the file ({header[filesz]}) than in memory ({header[memsz]})"
    if PT_LOAD not in kinds or PT_DYNAMIC not in kinds:
        return "no loadable segment" if PT_LOAD not in kinds else "no dynamic segment"
    return None


def _sections(data: bytes, order: str, layout: Layout, offset: int, entry: int, count: int, names: int) -> str | None:
    """What is wrong with the section header table (at `offset`, `count` entries of `entry` bytes, section
    names in section `names`), or None. Large counts and indices are in section 0 (``SHN_XINDEX``)."""
    fields, expected, (kind, start, length) = layout.section, layout.section_size, layout.section_fields
    if offset == 0 or offset + expected > len(data):
        return f"the section header table (at byte {offset}) is not in the file of {len(data)} bytes"
    if entry != expected:
        return f"section header size {entry}, expected {expected}"
    first = struct.unpack_from(order + fields, data, offset)
    count = count or first[length]
    names = first[6] if names == SHN_XINDEX else names
    if offset + count * entry > len(data):
        return f"the section header table ends at byte {offset + count * entry}, beyond the file's {len(data)}"
    if names >= count:
        return f"the section names are in section {names}, which does not exist ({count} sections)"
    for k in range(1, count):
        header = struct.unpack_from(order + fields, data, offset + k * entry)
        if header[kind] != SHT_NOBITS and header[start] + header[length] > len(data):
            return f"section {k} ends at byte {header[start] + header[length]}, beyond the file's {len(data)}"
    return None
