"""RINEX files as text: decompression (gzip, Unix compress, Hatanaka), header lookup, clear errors.

Every reader of a user's RINEX file (navigation here, observations in
:mod:`testbed.rinex`) starts from :func:`read_lines` and reports problems as a
:class:`RinexError` naming the file and the line, which the command prints
with exit code 2.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from testbed.schema import ConfigError

_COMPRESSED_MAGIC = (b"\x1f\x8b", b"\x1f\x9d", b"PK\x03\x04", b"BZh")


class RinexError(ConfigError):
    """A RINEX file that cannot be read as asked: the message names the file, the line and what was expected."""

    def __init__(self, path: str | Path, problem: str, line: int | None = None) -> None:
        super().__init__(path, [problem if line is None else f"line {line}: {problem}"])


@dataclass(frozen=True)
class RinexText:
    """A decompressed RINEX file: its lines, and where the header ends (index of END OF HEADER)."""

    path: Path
    lines: list[str]
    header_end: int
    ends_with_line_break: bool = True  # a file cut while it was written or copied usually does not

    def ends_here(self, line: int) -> str:
        """'; the file ends in this line (truncated file?)' when 1-based ``line`` is the file's last line
        and has no line break after it, else ''."""
        return "; the file ends in this line (truncated file?)" if (
            line == len(self.lines) and not self.ends_with_line_break) else ""

    @property
    def version(self) -> str:
        return self.lines[0][:9].strip()

    @property
    def file_type(self) -> str:
        return self.lines[0][20:21]

    def header(self, label: str) -> list[tuple[int, str]]:
        """(line number, line) of every header record with ``label`` (columns 61-80)."""
        return [(k + 1, ln) for k, ln in enumerate(self.lines[:self.header_end]) if ln[60:].strip() == label]

    def fail(self, problem: str, line: int | None = None) -> RinexError:
        return RinexError(self.path, problem, line)


def _decompress(path: Path, raw: bytes) -> bytes:
    is_crinex = raw[:80].find(b"CRINEX VERS") >= 0 or raw[:80].find(b"COMPACT RINEX") >= 0
    if not (raw.startswith(_COMPRESSED_MAGIC) or is_crinex):
        return raw
    import hatanaka

    try:
        return hatanaka.decompress(raw)
    except Exception as exc:  # the library raises its own types, ValueError and OSError
        raise RinexError(path, f"cannot decompress ({type(exc).__name__}: {str(exc).strip()[:200]}); expected a "
                               f"gzip, Unix compress, zip, bzip2 or Hatanaka-compressed RINEX file") from None


def read_lines(path: str | Path, what: str, file_type: str) -> RinexText:
    """The lines of a (possibly compressed) RINEX 2.xx/3.xx file of ``file_type`` ('O', 'N'), checked to be
    text with a complete header.

    ``what`` names the expected content in messages ("observation", "navigation").
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise RinexError(path, f"cannot read the {what} file ({exc.strerror or exc})") from None
    raw = _decompress(path, raw)
    if b"\x00" in raw[:65536]:
        raise RinexError(path, f"binary content (NUL bytes); expected a RINEX {what} file (text)")
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError as exc:
        try:
            text = raw.decode("latin-1")  # comments in other encodings: tolerated, data fields are ASCII
        except UnicodeDecodeError:  # pragma: no cover - latin-1 decodes any byte
            raise RinexError(path, f"not text at byte {exc.start}; expected a RINEX {what} file") from None
    lines = text.splitlines()
    if not lines or lines[0][60:].strip() != "RINEX VERSION / TYPE":
        first = lines[0][:80] if lines else ""
        raise RinexError(path, f"first line {first!r} is not a 'RINEX VERSION / TYPE' record; expected a RINEX "
                               f"{what} file", 1)
    end = next((k for k, ln in enumerate(lines) if ln[60:].strip() == "END OF HEADER"), None)
    if end is None:
        raise RinexError(path, f"no 'END OF HEADER' record in {len(lines)} lines (truncated header?)")
    text = RinexText(path, lines, end, ends_with_line_break=raw.rstrip(b"\x1a").endswith((b"\n", b"\r")))
    if text.version[:1] not in ("2", "3") or text.file_type != file_type:
        raise text.fail(f"version {text.version!r}, file type {text.file_type!r}: expected a RINEX 2.xx or 3.xx "
                        f"{what} file (type {file_type!r})", 1)
    return text


def rinex_float(field: str) -> float:
    """A RINEX number field (Fortran D exponents allowed; blank = 0)."""
    s = field.strip().replace("D", "E").replace("d", "e")
    return float(s) if s else 0.0
