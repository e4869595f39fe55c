"""Getting a lens file's text: the size limits, reading and decoding.

Files (and strings) over MAX_FILE_BYTES are refused before any parsing, as are lenses with more
than MAX_SURFACES surfaces (where the text shows it); a file must be UTF-8 (a leading
byte-order mark is dropped).
"""

from __future__ import annotations

from ..lensfields import Where, describe

#: Files (or strings) larger than this are refused before parsing.
MAX_FILE_BYTES = 1 << 20
#: Lenses with more surfaces than this are refused (before parsing where the text shows it).
MAX_SURFACES = 256


def read_bytes(path) -> bytes:
    """The file's bytes; size and read problems become LensError naming the file."""
    from ..safe_io import UnreadableFile, read_regular
    try:
        return read_regular(path, MAX_FILE_BYTES, "lens file")
    except UnreadableFile as exc:
        raise Where(path).error(exc.reason + ", refusing to parse it") from None


def read_text(path) -> str:
    """The file as UTF-8 text; size, read and decode problems become LensError naming the
    file."""
    where = Where(path)
    data = read_bytes(path)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise where.error(f"file is not UTF-8 text: undecodable byte 0x{data[exc.start]:02x} at "
                          f"line {line} (byte offset {exc.start})") from None
    return text[1:] if text.startswith("\ufeff") else text


def check_text(text, where: Where) -> None:
    """Refuse what is not a string, or larger than MAX_FILE_BYTES, before parsing it."""
    if not isinstance(text, str):
        raise where.error(f"expected the lens file's text as a string, got {describe(text)}")
    if len(text) > MAX_FILE_BYTES or len(text.encode("utf-8", "surrogatepass")) > MAX_FILE_BYTES:
        raise where.error(f"lens text is larger than {MAX_FILE_BYTES} bytes (1 MiB), refusing "
                          "to parse it")
