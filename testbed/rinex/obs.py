"""RINEX 2.xx and 3.xx observation files: GPS, Galileo and BeiDou code, Doppler and C/N0 over (epoch, satellite).

The reader walks the epoch records once in Python (the record boundaries
depend on each epoch's satellite count) and parses every measurement field
of every satellite record in one vectorised pass: the records are padded to
a fixed width, viewed as a byte matrix and each field column converted with
numpy. Phase (``L``) observables are not read: no monitor here uses them.

Kept: GPS satellites (system ``G``, or blank in 2.xx) and, in 3.xx files,
Galileo (``E``) and BeiDou (``C``) satellites; observation types whose code
starts with C (code), D (Doppler) or S (signal strength), under their RINEX 3
names (2.xx ``C1``/``P1``/``P2``/``C2``/``C5``/``D1``/``S1``... are renamed, see
:data:`V2_NAMES`; 2.xx files are read as GPS). Skipped, and counted: the other
systems' measurements (GLONASS, QZSS, NavIC, SBAS), event records (epoch flags
2-5) and cycle-slip records (flag 6). Epochs with flag 1 (power failure before
the epoch) are kept. Refused, naming the line and the value: a system letter
that is not RINEX 3's, and an observation code that RINEX 3.05 does not define
for a GPS, Galileo or BeiDou satellite (:func:`testbed.sensors.gnss.signals.code_problem`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from testbed.records import satellite_ids
from testbed.sensors.gnss.orbits import SYSTEM_NAMES
from testbed.sensors.gnss.rinex_text import RinexText, read_lines, rinex_float
from testbed.sensors.gnss.signals import RINEX_SYSTEMS, USED_SYSTEMS, code_problem
from testbed.sensors.gnss.timebase import gpst_calendar_to_gps_seconds

#: RINEX 2.xx observation codes -> the RINEX 3 names used here (GPS: P-code on L1/L2 is the W tracking)
V2_NAMES = {"C1": "C1C", "P1": "C1W", "C2": "C2L", "P2": "C2W", "C5": "C5Q", "D1": "D1C", "D2": "D2W",
            "D5": "D5Q", "S1": "S1C", "S2": "S2W", "S5": "S5Q"}
_KEPT_KINDS = ("C", "D", "S")
#: time systems of the tags, and their offset to GPS time (s): Galileo time is steered to GPS time (tags usable
#: as GPST); BeiDou time is GPST − 14 s (a BDT tag + 14 s is the GPST one)
_TIME_SYSTEMS = {"GPS": 0.0, "GAL": 0.0, "": 0.0, "BDT": 14.0}


@dataclass(frozen=True)
class RinexObs:
    """GPS, Galileo and BeiDou measurements of an observation file.

    t_tag : (E,) epoch time tags, s since the GPS epoch, in the *receiver's* time scale
        (true GPS time + the receiver clock offset, as a receiver writes them).
    prn : (S,) the satellites observed at least once, sorted by system (G, E, C) then PRN.
    system : (S,) their RINEX 3 system letters.
    values : observation code (RINEX 3 name, e.g. ``C1C``) -> (E, S) float, NaN where absent (a code a
        system does not declare is NaN for its satellites).
    types : the observation codes each system letter declares in the header.
    clock_offset_s : (E,) receiver clock offset written on the epoch line (NaN where blank).
    """

    path: Path
    version: str
    t_tag: NDArray
    prn: NDArray
    values: dict[str, NDArray]
    clock_offset_s: NDArray
    approx_pos_ecef: NDArray
    interval_s: float | None
    receiver_type: str
    comments: tuple[str, ...]
    skipped: dict[str, int] = field(default_factory=dict)  # what was not used, with counts
    system: NDArray | None = None
    types: dict[str, tuple[str, ...]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.system is None:
            object.__setattr__(self, "system", np.full(self.prn.shape, "G"))

    @property
    def epochs(self) -> int:
        return int(self.t_tag.size)

    @property
    def systems(self) -> tuple[str, ...]:
        """The system letters with at least one satellite, in G, E, C order."""
        return tuple(x for x in SYSTEM_NAMES if (self.system == x).any())

    @property
    def sat_id(self) -> NDArray:
        """RINEX 3 satellite identifiers (S,), e.g. ``"G05"``, ``"E12"``."""
        return satellite_ids(self.system, self.prn)


@dataclass
class _Records:
    """Satellite records collected from the epoch walk (one entry per satellite record)."""

    text: list[str] = field(default_factory=list)  # the record (continuation lines joined for 2.xx)
    sat: list[str] = field(default_factory=list)  # 3-character satellite id
    epoch: list[int] = field(default_factory=list)
    line: list[int] = field(default_factory=list)  # 1-based line number of the record's first line


def _header_types(text: RinexText) -> tuple[dict[str, list[str]], dict[str, int]]:
    """Observation types per system letter (2.xx: one list for every system, key '*'), and the header line
    of each system's first record. A 3.xx system letter that is not RINEX 3's, or a code RINEX 3.05 does not
    define for a GPS, Galileo or BeiDou satellite, is refused naming the line and the value."""
    types: dict[str, list[str]] = {}
    where: dict[str, int] = {}
    if text.version.startswith("2"):
        recs = text.header("# / TYPES OF OBSERV")
        if not recs:
            raise text.fail("no '# / TYPES OF OBSERV' header record")
        try:
            n = int(recs[0][1][:6])
        except ValueError:
            raise text.fail(f"unreadable observation type count {recs[0][1][:6]!r}", recs[0][0]) from None
        names = [ln[10 + 6 * j:12 + 6 * j].strip() for _, ln in recs for j in range(9)]
        types["*"] = [c for c in names if c][:n]
        where["*"] = recs[0][0]
        return types, where
    recs = text.header("SYS / # / OBS TYPES")
    if not recs:
        raise text.fail("no 'SYS / # / OBS TYPES' header record")
    sys = None
    for no, ln in recs:
        if ln[0] != " ":
            sys = ln[0]
            if sys not in RINEX_SYSTEMS:
                raise text.fail(f"system letter {sys!r} in 'SYS / # / OBS TYPES': expected one of RINEX 3's "
                                f"{', '.join(RINEX_SYSTEMS)}", no)
            try:
                int(ln[3:6])
            except ValueError:
                raise text.fail(f"unreadable observation type count {ln[3:6]!r}", no) from None
            types[sys] = []
            where[sys] = no
        if sys is None:
            raise text.fail("an observation-type continuation line before its system's line", no)
        codes = [ln[7 + 4 * j:10 + 4 * j].strip() for j in range(13) if ln[7 + 4 * j:10 + 4 * j].strip()]
        for c in codes:
            problem = code_problem(sys, c)
            if problem is not None:
                raise text.fail(f"{SYSTEM_NAMES.get(sys, sys)} observation type {problem}", no)
        types[sys] += codes
    return types, where


def _time_system(text: RinexText) -> float:
    """The offset (s) that turns the file's time tags into GPS time."""
    recs = text.header("TIME OF FIRST OBS")
    if recs:
        no, ln = recs[0]
        ts = ln[48:51].strip()
        if ts not in _TIME_SYSTEMS:
            raise text.fail(f"time system {ts!r}: expected GPS, Galileo or BeiDou time tags ('GPS', 'GAL', 'BDT', "
                            f"or blank in a GPS file)", no)
        return _TIME_SYSTEMS[ts]
    return 0.0


def _walk_v3(text: RinexText, rec: _Records, skipped: dict[str, int]) -> tuple[list[float], list[float]]:
    lines, n = text.lines, len(text.lines)
    t_tag, clock = [], []
    k = text.header_end + 1
    while k < n:
        ln = lines[k]
        if not ln.strip():
            k += 1
            continue
        if ln[0] != ">":
            raise text.fail(f"{ln[:40]!r}: expected an epoch record starting with '>'", k + 1)
        try:
            flag, nsat = int(ln[31:32] or "0"), int(ln[32:35])
        except ValueError:
            raise text.fail(f"unreadable epoch flag / satellite count {ln[29:35]!r}{text.ends_here(k + 1)}", k + 1) \
                from None
        if flag > 1:  # event (2-5: header lines follow) or cycle-slip records (6): not measurements here
            skipped["event records"] = skipped.get("event records", 0) + 1
            k += nsat + 1
            continue
        if k + nsat >= n:
            raise text.fail(f"epoch announces {nsat} satellites but the file ends after {n - k - 1} more lines "
                            f"(truncated file?)", k + 1)
        try:
            t = gpst_calendar_to_gps_seconds(int(ln[2:6]), int(ln[7:9]), int(ln[10:12]), int(ln[13:15]),
                                             int(ln[16:18]), float(ln[18:29]))
            clock.append(float(ln[41:56]) if ln[41:56].strip() else np.nan)
        except ValueError:
            raise text.fail(f"unreadable epoch time {ln[:35]!r}; expected '> yyyy mm dd hh mm ss.sssssss'"
                            f"{text.ends_here(k + 1)}", k + 1) from None
        e = len(t_tag)
        t_tag.append(t)
        body = lines[k + 1:k + 1 + nsat]
        rec.text += body
        rec.sat += [b[:3] for b in body]
        rec.epoch += [e] * nsat
        rec.line += range(k + 2, k + 2 + nsat)
        k += nsat + 1
    return t_tag, clock


def _walk_v2(text: RinexText, n_types: int, rec: _Records, skipped: dict[str, int]) -> tuple[list[float], list[float]]:
    lines, n = text.lines, len(text.lines)
    per_sat = -(-n_types // 5)
    t_tag, clock = [], []
    k = text.header_end + 1
    while k < n:
        ln = lines[k]
        if not ln.strip():
            k += 1
            continue
        try:
            flag, nsat = int(ln[28:29] or "0"), int(ln[29:32])
        except ValueError:
            raise text.fail(f"{ln[:32]!r}: expected an epoch record (yy mm dd hh mm ss.sssssss flag count)"
                            f"{text.ends_here(k + 1)}", k + 1) from None
        sat_lines = -(-nsat // 12) if flag <= 1 or flag == 6 else 0
        if flag > 1:
            skipped["event records"] = skipped.get("event records", 0) + 1
            k += 1 + nsat if flag < 6 else sat_lines + nsat * per_sat  # 6: cycle-slip records, data layout
            continue
        if k + sat_lines - 1 + nsat * per_sat >= n:
            raise text.fail(f"epoch announces {nsat} satellites but the file ends before their records (truncated "
                            f"file?)", k + 1)
        try:
            yy = int(ln[1:3])
            t = gpst_calendar_to_gps_seconds(yy + (2000 if yy < 80 else 1900), int(ln[4:6]), int(ln[7:9]),
                                             int(ln[10:12]), int(ln[13:15]), float(ln[15:26]))
            clock.append(float(ln[68:80]) if ln[68:80].strip() else np.nan)
        except ValueError:
            raise text.fail(f"unreadable epoch time {ln[:26]!r}; expected ' yy mm dd hh mm ss.sssssss'"
                            f"{text.ends_here(k + 1)}", k + 1) from None
        ids = "".join(lines[k + j][32:68].ljust(36) for j in range(sat_lines))
        sats = [ids[3 * j:3 * j + 3] for j in range(nsat)]
        e = len(t_tag)
        t_tag.append(t)
        first = k + sat_lines
        for j, sat in enumerate(sats):
            a = first + j * per_sat
            rec.text.append("".join(lines[a + i][:80].ljust(80) for i in range(per_sat)))
            rec.sat.append(sat)
            rec.epoch.append(e)
            rec.line.append(a + 1)
        k = first + nsat * per_sat
    return t_tag, clock


def _field_columns(text: RinexText, types: list[str]) -> dict[str, int]:
    """Kept observation code -> first column of its F14.3 field in a (joined) satellite record."""
    out = {}
    v2 = text.version.startswith("2")
    for j, code in enumerate(types):
        name = V2_NAMES.get(code, code) if v2 else code
        if name[:1] in _KEPT_KINDS and name not in out:
            out[name] = 80 * (j // 5) + 16 * (j % 5) if v2 else 3 + 16 * j
    return out


def _parse_fields(text: RinexText, records: list[str], lines: NDArray, columns: dict[str, int]) -> dict[str, NDArray]:
    """Every kept field of every record, parsed in one pass per observation type (NaN where blank)."""
    if not records:
        return {c: np.zeros(0) for c in columns}
    width = max(columns.values()) + 14
    block = "".join(r[:width].ljust(width) for r in records).encode("latin-1")
    chars = np.frombuffer(block, np.uint8).reshape(len(records), width)
    out = {}
    for code, c0 in columns.items():
        f = np.ascontiguousarray(chars[:, c0:c0 + 14])
        blank = (f == 32).all(1)
        # F14.3: the point in the field's 11th column, 3 digits after it. A field cut short (a truncated file)
        # or shifted (an edited one) would still convert, to another number: refused instead.
        digits = (f[:, 11:] >= ord("0")) & (f[:, 11:] <= ord("9"))
        misplaced = ~blank & ((f[:, 10] != ord(".")) | ~digits.all(1))
        f[blank, 13] = ord("0")
        try:
            v = f.view("S14").ravel().astype(np.float64)
        except ValueError:
            misplaced |= np.array([not _is_number(r.tobytes()) for r in f])
        if misplaced.any():
            bad = int(np.flatnonzero(misplaced)[0])
            line = int(lines[bad]) + c0 // 80
            raise text.fail(f"{code} field {f[bad].tobytes().decode('latin-1')!r}: expected a number in F14.3 (3 "
                            f"decimals, the point in the field's 11th column){text.ends_here(line)}", line) from None
        v[blank] = np.nan
        out[code] = v
    return out


def _is_number(s: bytes) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def _last_record_whole(text: RinexText, types: dict[str, list[str]], rec: _Records) -> None:
    """A file without a line break after its last line, that line a satellite record's, shorter than its
    observation types' fields: cut inside the record (its last fields would read as absent)."""
    n = len(text.lines)
    if text.ends_with_line_break or not rec.line:
        return
    v2 = text.version.startswith("2")
    n_types = len(types.get("*" if v2 else rec.sat[-1][:1], []))
    on_last = (n_types - 1) % 5 + 1 if v2 else n_types  # fields on the record's last line
    first_col = 0 if v2 else 3
    last_line = rec.line[-1] + (-(-n_types // 5) - 1 if v2 else 0)
    need = first_col + 16 * on_last - 2  # up to the last field's end (its LLI and SSI may be blank)
    if last_line == n and n_types and len(text.lines[-1].rstrip("\r")) < need:
        raise text.fail(f"satellite record {rec.sat[-1]!r} is {len(text.lines[-1])} characters long, its "
                        f"{n_types} observation types take {need}, and the file ends in this line without a line "
                        f"break: cut inside the record (truncated file?); if the record is whole, end the file "
                        f"with a line break", n)


def read_obs(path: str | Path) -> RinexObs:
    """GPS, Galileo and BeiDou code / Doppler / C/N0 of a RINEX 2.xx or 3.xx observation file (gzip and
    Hatanaka too)."""
    text = read_lines(path, "observation", "O")
    vers = text.version
    tag_offset_s = _time_system(text)
    types, where = _header_types(text)
    v2 = vers.startswith("2")
    used = {"G": types.get("*", [])} if v2 else {x: types[x] for x in USED_SYSTEMS if types.get(x)}
    used = {x: t for x, t in used.items() if t}
    if not used:
        raise text.fail(f"no GPS{'' if v2 else ', Galileo or BeiDou'} observation types in the header (systems "
                        f"{sorted(types)}): expected GPS{'' if v2 else ', Galileo or BeiDou'} measurements")
    columns = {x: _field_columns(text, t) for x, t in used.items()}
    if not any(c.startswith("C") for cols in columns.values() for c in cols):
        what = "GPS" if list(used) == ["G"] else "/".join(SYSTEM_NAMES[x] for x in used)
        listed = used["G"] if list(used) == ["G"] else {x: t for x, t in used.items()}
        raise text.fail(f"{what} observation types {listed}: none is a pseudorange (C1C, C1W, C2W... / C1, P1, P2 "
                        f"in RINEX 2); expected at least one code observation", where["*" if v2 else next(iter(used))])
    rec, skipped = _Records(), {}
    n_types = max(len(t) for t in used.values()) if v2 else 0
    t_tag, clock = _walk_v2(text, n_types, rec, skipped) if v2 else _walk_v3(text, rec, skipped)
    if not t_tag:
        raise text.fail("no observation epochs after the header")
    _last_record_whole(text, types, rec)
    sys = np.array([s[:1] if s[:1] != " " else "G" for s in rec.sat])
    line_all = np.asarray(rec.line)
    for letter in sorted(set(sys.tolist())):
        if letter not in RINEX_SYSTEMS:
            k = int(np.flatnonzero(sys == letter)[0])
            raise text.fail(f"satellite {rec.sat[k]!r}: system letter {letter!r} is not RINEX 3's (expected one of "
                            f"{', '.join(RINEX_SYSTEMS)})", int(line_all[k]))
    for letter in sorted(set(sys.tolist()) - set(used)):  # not read here, or no types declared for them
        skipped[f"system {letter} satellite records"] = int((sys == letter).sum())
    keep = np.flatnonzero(np.isin(sys, list(used)))
    if keep.size == 0:
        others = ", ".join(f"{k} {v}" for k, v in sorted(skipped.items())) or "none"
        names = "/".join(SYSTEM_NAMES[x] for x in used)
        raise text.fail(f"no {names} satellite records in its {len(t_tag)} epochs (the header declares {names} "
                        f"types {used['G'] if list(used) == ['G'] else used}, but no record starts with "
                        f"{'/'.join(used)}{'' if not v2 else ' or a blank'}; skipped: {others}); expected "
                        f"{names} measurements")
    try:
        prn_rec = np.array([int(rec.sat[i][1:3]) for i in keep], np.int64)
    except ValueError:
        bad = next(i for i in keep if not rec.sat[i][1:3].strip().isdigit())
        raise text.fail(f"satellite id {rec.sat[bad]!r}: expected a system letter and a 2-digit PRN",
                        rec.line[bad]) from None
    order = {x: k for k, x in enumerate(SYSTEM_NAMES)}  # columns sorted by system (G, E, C), then PRN
    sys_rec = sys[keep]
    key = np.array([order[x] for x in sys_rec], np.int64) * 100 + prn_rec
    uniq = np.unique(key)
    col = np.searchsorted(uniq, key)
    prn = uniq % 100
    system = np.array([tuple(SYSTEM_NAMES)[k] for k in uniq // 100], dtype="<U1")
    ep = np.asarray(rec.epoch, np.intp)[keep]
    E, S = len(t_tag), prn.size
    values: dict[str, NDArray] = {}
    for x, cols in columns.items():
        sel = np.flatnonzero(sys_rec == x)
        vals = _parse_fields(text, [rec.text[keep[i]] for i in sel], line_all[keep[sel]], cols)
        for code, v in vals.items():
            a = values.setdefault(code, np.full((E, S), np.nan))
            a[ep[sel], col[sel]] = v
    t = np.asarray(t_tag) + tag_offset_s
    if np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise text.fail(f"epoch {k + 1} is not after the one before it (time tags must increase)")
    approx = np.zeros(3)
    for no, ln in text.header("APPROX POSITION XYZ"):
        try:
            approx = np.array([rinex_float(ln[14 * j:14 * j + 14]) for j in range(3)])
        except ValueError:
            raise text.fail(f"unreadable APPROX POSITION XYZ {ln[:42]!r}", no) from None
    interval = None
    for no, ln in text.header("INTERVAL"):
        try:
            interval = float(ln[:10])
        except ValueError:
            raise text.fail(f"unreadable INTERVAL {ln[:10]!r}", no) from None
    rt = text.header("REC # / TYPE / VERS")
    comments = tuple(ln[:60].rstrip() for _, ln in text.header("COMMENT"))
    return RinexObs(path=text.path, version=vers, t_tag=t, prn=prn, values=values, clock_offset_s=np.asarray(clock),
                    approx_pos_ecef=approx, interval_s=interval, receiver_type=rt[0][1][20:40].strip() if rt else "",
                    comments=comments, skipped=skipped, system=system,
                    types={x: tuple(_field_columns(text, t)) for x, t in used.items()})

