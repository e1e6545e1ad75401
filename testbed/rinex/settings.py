"""Settings of ``testbed monitor``: how pseudoranges are formed from a RINEX file, and the error model.

A monitor configuration file (TOML) holds a ``[rinex]`` table (this model) and
an ``[integrity]`` table (the same :class:`IntegritySettings` as an approach
file: P_FA, P_MD, PL variant, service levels, FDE).
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, model_validator

from testbed.integrity.settings import IntegritySettings
from testbed.schema import StrictModel
from testbed.sensors.gnss.signals import code_problem

#: L1 code observations in order of preference, and second-frequency codes for the iono-free combination
L1_CODES = ("C1C", "C1W", "C1X", "C1P", "C1S", "C1L")
SECOND_CODES = ("C2W", "C2L", "C2X", "C2S", "C2P", "C5Q", "C5X", "C5I")
#: Galileo E1 and BeiDou B1 (B1C pilot, data+pilot, data; then B1I) codes, and their E5a / B2a partners
GALILEO_CODES = ("C1C", "C1X", "C1B")
BEIDOU_CODES = ("C1P", "C1X", "C1D", "C2I", "C2X")
GALILEO_SECOND_CODES = ("C5Q", "C5X", "C5I")
BEIDOU_SECOND_CODES = ("C5P", "C5X", "C5D")


class RinexSettings(StrictModel):
    """How pseudoranges are formed from the RINEX files and weighted (``[rinex]``)."""

    ionosphere: Literal["auto", "klobuchar", "iono_free", "off"] = Field(
        "auto", description="'iono_free': L1 with a second-frequency code (satellites without one are not used); "
                            "'klobuchar': the broadcast model from the navigation file's header; 'off': none (for "
                            "ranges already free of it, such as testbed export-rinex files); 'auto': off for testbed "
                            "exports, iono_free when the file has a second-frequency code, else klobuchar.")
    troposphere: Literal["auto", "saastamoinen", "off"] = Field(
        "auto", description="'saastamoinen' with a standard atmosphere; 'auto': off for testbed exports, else "
                            "saastamoinen.")
    error_model: Literal["seed", "rtklib", "user"] = Field(
        "seed", description="Pseudorange 1σ: 'seed' = σ_URA² + σ_tropo² + σ_air² (the VA-RAIM paper's eq. 27; the airborne "
                            "term × 2.59 for iono-free ranges) + the DO-229 Klobuchar residual when that model is "
                            "used; 'rtklib' = RTKLIB 2.4.3's single-point variance with its default options (for "
                            "side-by-side comparisons); 'user' = sqrt(sigma_a_m² + (sigma_b_m / sin el)²).")
    sigma_ura_m: float = Field(0.75, gt=0.0, le=100.0, description="'seed' model: σ_URA (m).")
    sigma_tropo_zenith_m: float = Field(0.12, ge=0.0, le=10.0, description="'seed' model: residual zenith "
                                                                          "troposphere 1σ (m).")
    sigma_a_m: float = Field(0.5, ge=0.0, le=1000.0, description="'user' model: elevation-independent 1σ (m).")
    sigma_b_m: float = Field(0.5, ge=0.0, le=1000.0, description="'user' model: 1σ at zenith that grows as 1/sin el (m).")
    elevation_mask_deg: float = Field(5.0, ge=0.0, lt=90.0, description="Satellites below this elevation are not used.")
    l1_codes: tuple[str, ...] = Field(L1_CODES, min_length=1, description="L1 code observations to use, in order of "
                                                                          "preference (the first present in the file).")
    second_codes: tuple[str, ...] = Field(SECOND_CODES, min_length=1, description="Second-frequency code "
                                                                                  "observations for iono_free, in "
                                                                                  "order of preference.")
    systems: Literal["auto"] | tuple[Literal["G", "E", "C"], ...] = Field(
        "auto", description="Satellite systems to use (RINEX 3 letters: G GPS, E Galileo, C BeiDou). The snapshot "
                            "monitors solve one receiver clock per system (the inter-system bias is estimated, not "
                            "assumed): 'auto' uses every observed system with records in the navigation file (the "
                            "others skipped, the summary says why); a list uses those systems, and each must be in "
                            "both files.")
    galileo_codes: tuple[str, ...] = Field(GALILEO_CODES, min_length=1, description="Galileo E1 code observations, "
                                                                                     "in order of preference.")
    beidou_codes: tuple[str, ...] = Field(BEIDOU_CODES, min_length=1, description="BeiDou code observations (B1C "
                                                                                   "C1P/C1X/C1D, B1I C2I/C2X), in "
                                                                                   "order of preference.")
    galileo_second_codes: tuple[str, ...] = Field(GALILEO_SECOND_CODES, min_length=1,
                                                  description="Galileo second-frequency (E5a) codes for iono_free.")
    beidou_second_codes: tuple[str, ...] = Field(BEIDOU_SECOND_CODES, min_length=1,
                                                 description="BeiDou second-frequency (B2a) codes for iono_free.")
    origin: tuple[float, float, float] | Literal["first_fix"] = Field(
        "first_fix", description="Origin of the local ENU frame the monitors report in: [lat_deg, lon_deg, h_m], or "
                                 "'first_fix' = the first epoch's preliminary position.")

    @model_validator(mode="after")
    def _codes(self):
        for name, codes, band in (("l1_codes", self.l1_codes, "1"), ("second_codes", self.second_codes, "25")):
            bad = [c for c in codes if len(c) != 3 or c[0] != "C" or c[1] not in band]
            if bad:
                raise ValueError(f"{name}: {bad} are not {'L1' if band == '1' else 'L2/L5'} code observation names "
                                 f"(RINEX 3, such as {codes[0] if not bad else ('C1C' if band == '1' else 'C2W')})")
        for name, codes, system in (("galileo_codes", self.galileo_codes, "E"), ("beidou_codes", self.beidou_codes, "C"),
                                    ("galileo_second_codes", self.galileo_second_codes, "E"),
                                    ("beidou_second_codes", self.beidou_second_codes, "C")):
            bad = [p for p in (code_problem(system, c) if c[:1] == "C" else f"{c!r} is not a code observation"
                               for c in codes) if p]
            if bad:
                raise ValueError(f"{name}: {'; '.join(bad)}")
        if self.systems != "auto" and (not self.systems or len(set(self.systems)) != len(self.systems)):
            raise ValueError(f"systems: expected 'auto' or distinct letters among G, E, C, got {list(self.systems)}")
        if self.error_model == "user" and self.sigma_a_m == 0.0 and self.sigma_b_m == 0.0:
            raise ValueError("sigma_a_m = sigma_b_m = 0: the 'user' model would weight every range by 1/0; "
                             "expected at least one of them > 0")
        if self.origin != "first_fix":
            lat, lon, h = self.origin
            if not (-90 <= lat <= 90 and -180 <= lon <= 360 and -1000 <= h <= 1e5):
                raise ValueError(f"origin: expected [lat_deg -90..90, lon_deg -180..360, h_m -1000..100000], "
                                 f"got {list(self.origin)}")
        return self


class MonitorIntegritySettings(IntegritySettings):
    """An approach file's [integrity] table, with fault exclusion on by default (a recorded file cannot be re-flown)."""

    fde: bool = Field(True, description="Fault exclusion after an alert (testbed.integrity.fde); on by default here.")


class MonitorFileConfig(StrictModel):
    """A ``testbed monitor --config`` file."""

    rinex: RinexSettings = Field(default_factory=RinexSettings, description="pseudorange formation and error "
                                                                            "model")
    integrity: MonitorIntegritySettings = Field(default_factory=MonitorIntegritySettings,
                                                description="integrity settings; fault exclusion on by default")
    monitor: dict[str, dict[str, Any]] = Field(default_factory=dict,
                                               description="each monitor's own options, `[monitor.<name>]`, as in "
                                                           "an approach file (checked by the monitor's options model "
                                                           "when the file is read)")
