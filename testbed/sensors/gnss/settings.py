"""Settings of the GNSS sensor (the ``[gnss]`` table of an approach file).

Defaults reproduce the VA-RAIM paper's error model (docs/design/integrity.md §1: its eq. 27,
DO-229 24-satellite almanac, 5° mask), GPS only. ``constellations`` adds the nominal
Galileo and BeiDou-3 constellations, each with its own ``[gnss.<name>]`` table (mask,
health, cap, integrity support data); ``error_model = "dfmc"`` selects the
dual-frequency iono-free model with per-constellation σ_URA / σ_URE / b_nom
(docs/design/gnss.md). Every field is documented here; the config loader composes this model.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator, model_validator

from testbed.schema import StrictModel
from testbed.sensors.gnss.errors import UserErrorModel


def file_digest(path: Path | None) -> str:
    """SHA-256 of a file's content (hex), or a note saying why there is none (a missing file is refused by the
    preflight before any geometry is computed)."""
    if path is None:
        return "no file"
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError as exc:
        return f"unreadable {path}: {exc.strerror or exc}"


class SatelliteCap(StrictModel):
    """From ``from_s`` (s after the approach's start) on, at most ``max_satellites`` are tracked."""

    from_s: float = Field(..., ge=0.0, description="the cap applies from this time on, s after the approach's "
                                                   "start")
    max_satellites: int = Field(..., ge=0, le=64, description="satellites tracked at most (the highest kept; "
                                                              "the rest reported EXCLUDED)")


#: C/N0 (dB-Hz) by elevation (deg) of an airborne L1 C/A antenna: an assumption (docs/design/dpe.md §2.6), labelled
CN0_BY_ELEVATION = {5.0: 38.0, 15.0: 41.0, 30.0: 43.5, 60.0: 45.0, 90.0: 45.5}


class CorrelatorSettings(StrictModel):
    """Correlator outputs on a code-delay grid (``[gnss.correlators]``), read by the ``dpe`` monitor."""

    bandwidth_chips: float = Field(1.0, gt=0.0, le=50.0,
                                   description="one-sided brick-wall front-end bandwidth in chip rates "
                                               "(1 = 2.046 MHz double-sided)")
    coherent_s: float = Field(0.02, gt=0.0, le=0.02, description="coherent integration T (s); ≤ one data bit")
    n_noncoherent: int = Field(50, ge=1, le=1000, description="blocks N_b per epoch (disjoint intervals)")
    delay_step_m: float = Field(2.0, gt=0.0, le=30.0, description="delay grid spacing Δ (m)")
    half_window_m: float = Field(1000.0, gt=0.0, le=5000.0, description="delay window ±(m) about the reference")
    cn0_by_elevation: dict[float, float] = Field(
        default_factory=lambda: dict(CN0_BY_ELEVATION),
        description="C/N0 (dB-Hz) at elevations (deg), linear between, held outside")
    cn0_offset_db: float = Field(0.0, ge=-30.0, le=20.0, description="added to every C/N0 (dB)")
    residual_doppler_hz: float = Field(0.0, ge=0.0, lt=50.0,
                                       description="carrier tracking's residual frequency error |Δf| (Hz): the "
                                                   "coherent amplitude falls by |sinc(Δf·T)|; < 1/T")
    synthesis: Literal["fast", "exact"] = Field(
        "fast", description="'exact': N_b noise draws per satellite (both statistics); 'fast': the power "
                            "statistic from (2 + echoes) draws of its exact second moments")
    statistic: Literal["pow", "mag"] = Field(
        "pow", description="what the receiver reports: Σ_b|y_b|² ('pow', the likelihood's) or "
                           "(1/N_b)Σ_b|y_b| ('mag', the DPE paper's; needs synthesis = 'exact')")
    multipath: Literal["off", "ground"] = Field(
        "off", description="'ground': a specular ground echo, delay 2·h_agl·sin(el), its phase from the path")
    ground_echo_db: float = Field(-20.0, le=0.0, description="ground echo amplitude relative to the direct (dB)")
    pseudorange_source: Literal["model", "correlator"] = Field(
        "model", description="the pseudoranges every monitor reads: 'model' = the VA-RAIM paper's error model drawn "
                             "directly; 'correlator' = each channel's correlogram peak (the DPE's signal: its SIS, "
                             "noise, code fault and echo), σ from the Cramér-Rao bound at the estimated C/N0 "
                             "(testbed.sensors.gnss.code_tracking)")

    @field_validator("cn0_by_elevation")
    @classmethod
    def _table(cls, v):
        if not v:
            raise ValueError("expected at least one elevation: C/N0 pair")
        for el, cn0 in v.items():
            if not (0.0 <= el <= 90.0 and 10.0 <= cn0 <= 70.0):
                raise ValueError(f"expected elevations in [0, 90] deg and C/N0 in [10, 70] dB-Hz, got {el}: {cn0}")
        return dict(sorted(v.items()))

    @model_validator(mode="after")
    def _consistent(self):
        if self.synthesis == "fast" and self.n_noncoherent < 20:
            raise ValueError(f"synthesis: 'fast' draws Σ_b|w_b|² as a Gaussian, valid for n_noncoherent ≥ 20 "
                             f"(got {self.n_noncoherent}); use synthesis = 'exact'")
        if self.statistic == "mag" and self.synthesis != "exact":
            raise ValueError("statistic: 'mag' needs synthesis = 'exact' (the fast synthesis draws the power)")
        if self.half_window_m < 10 * self.delay_step_m:
            raise ValueError(f"half_window_m: expected at least 10 delay steps ({10 * self.delay_step_m:g} m), "
                             f"got {self.half_window_m:g}")
        return self


#: Constellation names of ``[gnss] constellations``, and the RINEX 3 system letter of each.
CONSTELLATION_SYSTEMS = {"gps": "G", "galileo": "E", "beidou": "C"}
#: The PRNs a system's satellites may carry (RINEX 3: G01-G32, E01-E36, C01-C63).
PRN_RANGES = {"gps": (1, 32), "galileo": (1, 36), "beidou": (1, 63)}


class ConstellationSettings(StrictModel):
    """One constellation's receiver settings and integrity support data (``[gnss.gps]``, ``[gnss.galileo]``,
    ``[gnss.beidou]``). The defaults are the same for every system (docs/design/gnss.md §3)."""

    elevation_mask_deg: float | None = Field(
        None, ge=0.0, lt=90.0, description="elevation mask of this constellation (deg); None = [gnss] "
                                           "elevation_mask_deg")
    excluded_prns: list[int] = Field(
        default_factory=list, description="PRNs of this constellation treated as unhealthy (never tracked), "
                                          "e.g. [11, 14]")
    max_satellites: int | None = Field(
        None, ge=0, le=64, description="satellites of this constellation tracked at most at any epoch (the "
                                       "highest kept, the rest reported EXCLUDED); None = no cap")
    sigma_ura_m: float = Field(
        0.75, gt=0.0, le=100.0, description="'dfmc' error model: σ_URA, the clock/ephemeris error overbound the "
                                            "monitors are told (m, 1σ); ARAIM ADD v3.1 App. D LPV-200 example")
    sigma_ure_m: float = Field(
        0.50, gt=0.0, le=100.0, description="'dfmc' error model: σ_URE, the clock/ephemeris error actually drawn "
                                            "(m, 1σ); at most sigma_ura_m")
    b_nom_m: float = Field(
        0.50, ge=0.0, le=100.0, description="'dfmc' error model: b_nom, the nominal bias bound carried for integrity "
                                            "(m); a bound, not drawn (docs/design/gnss.md §3)")
    orbit_source: Literal["nominal", "rinex_nav", "yuma", "sem"] = Field(
        "nominal", description="where this constellation's orbits come from: 'nominal' (GPS: the [gnss] "
                               "almanac_source, the DO-229 almanac by default; Galileo, BeiDou: their nominal "
                               "slots), 'rinex_nav' (this system's broadcast records in the RINEX 2/3 navigation "
                               "file orbit_path, per satellite the one nearest the start; satellites without a "
                               "record within 2 h of it are not tracked), 'yuma' or 'sem' (GPS only: a YUMA or SEM "
                               "almanac, its week placed by [gnss] almanac_week)")
    orbit_path: Path | None = Field(
        None, description="the file of orbit_source 'rinex_nav' / 'yuma' / 'sem', relative to the approach file")

    @field_validator("excluded_prns")
    @classmethod
    def _distinct(cls, v):
        if len(set(v)) != len(v):
            raise ValueError(f"expected distinct PRNs, got {v}")
        return sorted(v)

    @model_validator(mode="after")
    def _ure_below_ura(self):
        if self.sigma_ure_m > self.sigma_ura_m:
            raise ValueError(f"sigma_ure_m = {self.sigma_ure_m} exceeds sigma_ura_m = {self.sigma_ura_m}: the drawn "
                             "error's sigma is expected at most the integrity overbound")
        return self


def checked_constellation_set(names: list[str]) -> list[str]:
    """``names`` if it is a valid ``[gnss] constellations`` list (known names, at least one, each once), else a
    ValueError saying what was expected (an approach's value and a campaign's constellation axis alike)."""
    unknown = [n for n in names if n not in CONSTELLATION_SYSTEMS]
    if unknown:
        raise ValueError(f"unknown constellation {unknown[0]!r}: expected some of {list(CONSTELLATION_SYSTEMS)}")
    if not names or len(set(names)) != len(names):
        raise ValueError(f"expected at least one constellation, each once, got {names}")
    return names


class GnssSettings(StrictModel):
    """GNSS receiver, constellation and error-model settings."""

    constellations: list[str] = Field(
        default_factory=lambda: ["gps"],
        description="constellations tracked, some of 'gps' (the almanac below), 'galileo' (the nominal 24/3/1 "
                    "slots) and 'beidou' (BeiDou-3: 24 MEO + 3 IGSO + 3 GEO nominal orbits), in this order "
                    "in the satellite slots; each one's orbits from a file instead: [gnss.<name>] orbit_source")
    gps: ConstellationSettings = Field(default_factory=ConstellationSettings,
                                       description="GPS: orbits, mask, health, cap, integrity support data")
    galileo: ConstellationSettings = Field(default_factory=ConstellationSettings,
                                           description="Galileo: orbits, mask, health, cap, integrity support data")
    beidou: ConstellationSettings = Field(default_factory=ConstellationSettings,
                                          description="BeiDou: orbits, mask, health, cap, integrity support data")
    error_model: Literal["seed", "dfmc"] = Field(
        "seed", description="'seed': the VA-RAIM paper's eq. 27 with one sigma_ura_m for every system, drawn with "
                            "the σ the monitors are told (the reproductions' model); 'dfmc': dual-frequency "
                            "iono-free (L1/L5, E1/E5a, B1C/B2a) with each constellation's σ_URA (told), σ_URE "
                            "(drawn) and b_nom, and the airborne curve user_error")
    user_error: UserErrorModel = Field(
        "wgc_m3", description="'dfmc' error model: airborne multipath + noise curve (docs/design/gnss.md §3); "
                              "'wgc_m3' is eq. 27's")
    inter_system_bias_sigma_m: float = Field(
        10.0, ge=0.0, le=1e4, description="1σ of each non-GPS constellation's receiver clock offset from GPS "
                                          "time (m), drawn once per trial and held (one oscillator; the "
                                          "monitors estimate one clock per constellation)")

    rate_hz: float = Field(1.0, gt=0.0, le=100.0,
                           description="measurement rate (Hz); the truth is decimated to it inside synthesize_gnss")
    almanac_source: Literal["do229", "yuma", "sem", "rinex_nav"] = Field(
        "do229", description="GPS's orbits: shipped DO-229 24-sat almanac, a YUMA or SEM file or a RINEX 3 nav file "
                             "(or [gnss.gps] orbit_source, not both)")
    almanac_path: Path | None = Field(None, description="file for almanac_source 'yuma' / 'sem' / 'rinex_nav', "
                                                        "relative to the approach file")
    almanac_week: Literal["auto", "periodic", "nearest_rollover"] = Field(
        "auto", description="placing a 10-bit almanac week in time: 'periodic' (toa moved to the week "
                            "nearest the flight; default for DO-229) or 'nearest_rollover' (default for YUMA, SEM)")
    elevation_mask_deg: float = Field(5.0, ge=0.0, lt=90.0, description="elevation mask (deg above local horizon)")
    terrain_masking: bool = Field(True, description="mask satellites whose line of sight hits the terrain")
    airframe_masking: bool = Field(True, description="mask satellites below the antenna plane (body x-y plane)")
    airframe_mask_deg: float = Field(0.0, ge=-30.0, lt=90.0,
                                     description="minimum elevation above the antenna plane (deg)")
    sigma_ura_m: float = Field(0.75, ge=0.0, description="σ_URA, signal-in-space error 1σ (m)")
    sigma_tropo_zenith_m: float = Field(0.12, ge=0.0,
                                        description="residual troposphere 1σ at zenith (m), the VA-RAIM paper's eq. 27 factor")
    multipath_tau_s: float | None = Field(
        None, gt=0.0, description="multipath correlation time (s), first-order Gauss-Markov; None = white")
    ura_tropo_tau_s: float | None = Field(
        None, gt=0.0, description="correlation time of the URA + troposphere residual (s); None = white")
    range_rate_sigma_m_s: float = Field(0.05, ge=0.0, description="range-rate (Doppler) noise 1σ (m/s), white")
    clock_model: bool = Field(True, description="two-state receiver clock (bias, drift random walk); "
                                                "False = zero clock")
    schedule: list[SatelliteCap] = Field(
        default_factory=list, description="caps on the satellites tracked over time (the highest kept; the rest "
                                          "reported EXCLUDED): steeper walls than the terrain model, or a study "
                                          "of 0-3 satellites")
    correlators: CorrelatorSettings = Field(default_factory=CorrelatorSettings,
                                            description="correlator outputs (synthesised when a monitor reads them)")
    clock_bias0_sigma_m: float = Field(100.0, ge=0.0, description="initial receiver clock bias 1σ (m)")
    clock_drift0_sigma_m_s: float = Field(1.0, ge=0.0, description="initial receiver clock drift 1σ (m/s)")
    clock_sf_m2_s: float = Field(
        9.0e-3, ge=0.0, description="clock white-FM spectral density S_f = c²·h0/2 (m²/s); TCXO h0 = 2e-19")
    clock_sg_m2_s3: float = Field(
        3.55e-2, ge=0.0, description="clock random-walk-FM density S_g = c²·2π²·h-2 (m²/s³); TCXO h-2 = 2e-20")

    @field_validator("schedule")
    @classmethod
    def _schedule_ordered(cls, v):
        times = [c.from_s for c in v]
        if times != sorted(times) or len(set(times)) != len(times):
            raise ValueError(f"expected strictly increasing from_s, got {times}")
        return v

    @field_validator("constellations")
    @classmethod
    def _known_constellations(cls, v):
        return checked_constellation_set(v)

    @model_validator(mode="after")
    def _constellation_tables(self):
        for name, (lo, hi) in PRN_RANGES.items():
            cs = getattr(self, name)
            if name not in self.constellations and name in self.model_fields_set:
                raise ValueError(f"{name}: settings given for a constellation not in constellations = "
                                 f"{self.constellations}")
            bad = [p for p in cs.excluded_prns if not lo <= p <= hi]
            if bad:
                raise ValueError(f"{name}.excluded_prns: PRN(s) {bad} out of range: expected {lo}-{hi}")
            self._check_orbit_source(name, cs)
        if self.error_model == "seed":  # keys only the DFMC model reads are refused, not ignored
            unread = [f"{n}.{k}" for n in CONSTELLATION_SYSTEMS for k in ("sigma_ura_m", "sigma_ure_m", "b_nom_m")
                      if k in getattr(self, n).model_fields_set]
            unread += ["user_error"] if "user_error" in self.model_fields_set else []
            if unread:
                raise ValueError(f"{', '.join(unread)}: read by error_model = 'dfmc' only (the seed model uses "
                                 f"sigma_ura_m for every system); set error_model = 'dfmc' or remove them")
        if self.correlators.pseudorange_source == "correlator" and self.constellations != ["gps"]:
            raise ValueError(f"correlators.pseudorange_source: 'correlator' synthesises GPS L1 C/A correlograms "
                             f"only; expected constellations = ['gps'] with it, got {self.constellations}")
        return self

    def _check_orbit_source(self, name: str, cs: ConstellationSettings) -> None:
        if cs.orbit_source == "nominal" and cs.orbit_path is not None:
            raise ValueError(f"{name}.orbit_path: read only with orbit_source 'rinex_nav', 'yuma' or 'sem' (it is "
                             f"'nominal'); set orbit_source or remove orbit_path")
        if cs.orbit_source != "nominal" and cs.orbit_path is None:
            raise ValueError(f"{name}.orbit_path: required when orbit_source is {cs.orbit_source!r}")
        if cs.orbit_source in ("yuma", "sem") and name != "gps":
            raise ValueError(f"{name}.orbit_source: {cs.orbit_source!r} is a GPS almanac format; expected "
                             f"'nominal' or 'rinex_nav' for {name}")
        if name == "gps" and cs.orbit_source != "nominal" and self.almanac_source != "do229":
            raise ValueError(f"gps.orbit_source = {cs.orbit_source!r} and almanac_source = "
                             f"{self.almanac_source!r} both name GPS's orbits; expected one of them")

    def orbit_source_of(self, name: str) -> tuple[str, Path | None, str]:
        """Where constellation ``name``'s orbits come from: (source, file, the key naming the file), source one of
        'nominal', 'rinex_nav', 'yuma', 'sem' (GPS's 'nominal' is ``almanac_source``: 'do229' there is 'nominal')."""
        cs = getattr(self, name)
        if name == "gps" and cs.orbit_source == "nominal":
            source = "nominal" if self.almanac_source == "do229" else self.almanac_source
            return source, self.almanac_path, "gnss.almanac_path"
        return cs.orbit_source, cs.orbit_path, f"gnss.{name}.orbit_path"

    @property
    def orbit_files(self) -> list[Path]:
        """The orbit files the tracked constellations read (each once, in constellation order)."""
        out = []
        for name in self.constellations:
            source, path, _ = self.orbit_source_of(name)
            if source != "nominal" and path is not None and path not in out:
                out.append(path)
        return out

    def geometry_key(self) -> str:
        """JSON of the settings the geometry reads (constellations, orbit sources and the content of their files,
        masks, health, caps, schedule, rate): two settings with one key give one geometry (a campaign caches
        it on this). A file is keyed on its content (SHA-256): a file edited between two cells is another sky,
        one file under two paths is one."""
        geo = {"constellations", "almanac_source", "almanac_path", "almanac_week", "elevation_mask_deg",
               "terrain_masking", "airframe_masking", "airframe_mask_deg", "schedule", "rate_hz"}
        per = {"elevation_mask_deg", "excluded_prns", "max_satellites", "orbit_source"}
        d = self.model_dump(mode="json", include=geo - {"almanac_path"})
        d |= {n: getattr(self, n).model_dump(mode="json", include=per) for n in self.constellations}
        d["orbit_files"] = {n: file_digest(self.orbit_source_of(n)[1]) for n in self.constellations
                            if self.orbit_source_of(n)[0] != "nominal"}
        return json.dumps(d, sort_keys=True)

    @property
    def systems(self) -> tuple[str, ...]:
        """The RINEX 3 system letters of ``constellations``, in order."""
        return tuple(CONSTELLATION_SYSTEMS[n] for n in self.constellations)

    def constellation(self, system: str) -> ConstellationSettings:
        """The settings of the constellation whose system letter is ``system``."""
        name = {v: k for k, v in CONSTELLATION_SYSTEMS.items()}[system]
        return getattr(self, name)

    @property
    def correlator_pseudoranges(self) -> bool:
        """True when the pseudoranges come from the correlograms (which must then be synthesised)."""
        return self.correlators.pseudorange_source == "correlator"

    @model_validator(mode="after")
    def _path_needed(self):
        if self.almanac_source != "do229" and self.almanac_path is None:
            raise ValueError(f"almanac_path: required when almanac_source is {self.almanac_source!r}")
        return self
