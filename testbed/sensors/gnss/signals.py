"""GNSS signals as RINEX 3.05 names them: carrier frequencies, valid observation codes, the testbed's signals.

A RINEX 3 observation code is a type letter (C code, L phase, D Doppler,
S signal strength), a band digit and an attribute letter (the tracking mode),
e.g. ``C1C``. The valid band/attribute pairs of the systems the testbed reads
(RINEX 3.05, IGS/RTCM-SC104, 2020, §5.1 and Tables A2/A4/A5...):

* GPS ``G``: L1 = band 1 (C S L X P W Y M N), L2 = band 2 (C D S L X P W Y M N),
  L5 = band 5 (I Q X).
* Galileo ``E``: E1 = band 1 (A B C X Z), E5a = 5 (I Q X), E5b = 7 (I Q X),
  E5 = 8 (I Q X), E6 = 6 (A B C X Z).
* BeiDou ``C``: B1I = band 2 (I Q X), B1C = band 1 (D P X; A for B1A), B2a = 5
  (D P X), B2I/B2b = 7 (I Q X D P Z), B2 = 8 (D P X), B3I = 6 (I Q X; A for B3A).
  (RINEX 3.02 wrote B1I as band 1, ``C1I``; 3.03 and later as band 2, ``C2I``.)

The signals the export writes (:data:`SIGNALS`): the pilot or combined
channel a modern receiver tracks: GPS L1 C/A ``1C``, L5 ``5Q`` (pilot);
Galileo E1 ``1C`` (E1-C pilot), E5a ``5Q`` (pilot); BeiDou B1C ``1P`` (pilot) or
B1I ``2I``, B2a ``5P`` (pilot).
"""

from __future__ import annotations

from dataclasses import dataclass

from testbed.frames import C_LIGHT

#: band digit -> carrier frequency (Hz), per system
FREQUENCY_HZ: dict[str, dict[str, float]] = {
    "G": {"1": 1575.42e6, "2": 1227.60e6, "5": 1176.45e6},
    "E": {"1": 1575.42e6, "5": 1176.45e6, "7": 1207.14e6, "8": 1191.795e6, "6": 1278.75e6},
    "C": {"1": 1575.42e6, "2": 1561.098e6, "5": 1176.45e6, "7": 1207.14e6, "8": 1191.795e6, "6": 1268.52e6},
}
#: band digit -> valid attribute letters (RINEX 3.05), per system
ATTRIBUTES: dict[str, dict[str, str]] = {
    "G": {"1": "CSLXPWYMN", "2": "CDSLXPWYMN", "5": "IQX"},
    "E": {"1": "ABCXZ", "5": "IQX", "7": "IQX", "8": "IQX", "6": "ABCXZ"},
    "C": {"1": "DPXA", "2": "IQX", "5": "DPX", "7": "IQXDPZ", "8": "DPX", "6": "IQXA"},
}
#: observation type letters of RINEX 3 (code, phase, Doppler, signal strength)
OBSERVATION_KINDS = "CLDS"
#: RINEX 3 satellite system letters (GPS, GLONASS, Galileo, BeiDou, QZSS, NavIC, SBAS)
RINEX_SYSTEMS = "GRECJIS"
#: the systems whose measurements the testbed uses (it has their orbits)
USED_SYSTEMS = "GEC"


@dataclass(frozen=True)
class Signal:
    """A signal the export writes: its system, RINEX band + attribute (``1C``) and carrier frequency."""

    name: str
    system: str
    code: str
    frequency_hz: float

    def observation(self, kind: str) -> str:
        """The RINEX 3 observation code of ``kind`` ('C', 'D', 'S', 'L') on this signal, e.g. ``C1P``."""
        return kind + self.code


SIGNALS: dict[str, Signal] = {s.name: s for s in (
    Signal("L1", "G", "1C", FREQUENCY_HZ["G"]["1"]),
    Signal("L5", "G", "5Q", FREQUENCY_HZ["G"]["5"]),
    Signal("E1", "E", "1C", FREQUENCY_HZ["E"]["1"]),
    Signal("E5a", "E", "5Q", FREQUENCY_HZ["E"]["5"]),
    Signal("B1C", "C", "1P", FREQUENCY_HZ["C"]["1"]),
    Signal("B1I", "C", "2I", FREQUENCY_HZ["C"]["2"]),
    Signal("B2a", "C", "5P", FREQUENCY_HZ["C"]["5"]),
)}
#: the first (single-frequency) signal of each system by default, and the second of the dual-frequency pair
FIRST_SIGNAL = {"G": "L1", "E": "E1", "C": "B1C"}
SECOND_SIGNAL = {"G": "L5", "E": "E5a", "C": "B2a"}


def code_problem(system: str, code: str) -> str | None:
    """Why ``code`` is not a RINEX 3.05 observation code of ``system`` (None when it is, or when the system is
    one the testbed does not check: GLONASS, QZSS, NavIC, SBAS)."""
    if system not in ATTRIBUTES:
        return None
    if len(code) != 3 or code[0] not in OBSERVATION_KINDS:
        return f"{code!r} is not a RINEX 3 observation code (type {'/'.join(OBSERVATION_KINDS)}, band, attribute)"
    band, attr = code[1], code[2]
    bands = ATTRIBUTES[system]
    if band not in bands:
        return f"{code!r}: band {band} is not a {system} band in RINEX 3.05 (expected one of {', '.join(bands)})"
    if attr not in bands[band]:
        return (f"{code!r}: attribute {attr} is not a {system} band-{band} tracking mode in RINEX 3.05 "
                f"(expected one of {', '.join(bands[band])})")
    return None


def wavelength_m(system: str, band: str) -> float:
    """Carrier wavelength (m) of a system's band."""
    return C_LIGHT / FREQUENCY_HZ[system][band]


__all__ = ["ATTRIBUTES", "FIRST_SIGNAL", "FREQUENCY_HZ", "OBSERVATION_KINDS", "RINEX_SYSTEMS", "SECOND_SIGNAL",
           "SIGNALS", "Signal", "USED_SYSTEMS", "code_problem", "wavelength_m"]
