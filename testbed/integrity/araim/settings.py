"""Settings of the ARAIM monitor: the integrity support message (ISM) and the risk allocation.

The ISM is what the ground segment broadcasts per constellation (σ_URA, σ_URE,
b_nom, P_sat, P_const and their mean fault durations); the allocation is the
airborne side (P_HMI, P_FA, P_THRES, P_EMT, the PL tolerance, the exposure
model). Defaults and the ``add_v31`` preset are explained in docs/design/araim.md §1.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator

from testbed.integrity.levels import SERVICE_LEVELS
from testbed.schema import StrictModel
from testbed.sensors.gnss.errors import UserErrorModel  # the σ_user curves: the GNSS sensor's

#: the systems a row may belong to, by code (the row's ``constellation`` index)
SYSTEMS: tuple[str, ...] = ("GPS", "Galileo", "BeiDou", "GLONASS")



class ConstellationIsm(StrictModel):
    """The integrity support data of one constellation (applies to each of its satellites)."""

    sigma_ura_m: float = Field(0.75, gt=0.0, description="σ_URA: the clock/ephemeris error overbound used for "
                                                         "integrity (m, 1σ)")
    sigma_ure_m: float = Field(0.50, gt=0.0, description="σ_URE: the clock/ephemeris error used for accuracy and "
                                                         "continuity (m, 1σ)")
    b_nom_m: float = Field(0.50, ge=0.0, description="b_nom: the nominal bias bound for integrity (m)")
    b_cont_m: float = Field(0.0, ge=0.0, description="b_cont: the nominal bias for accuracy and continuity (m)")
    p_sat: float = Field(1e-5, ge=0.0, lt=1.0, description="P_sat: prior probability of a satellite fault at any "
                                                           "instant")
    p_const: float = Field(1e-4, ge=0.0, lt=1.0, description="P_const: prior probability of a constellation-wide "
                                                             "fault at any instant")
    mfd_sat_h: float = Field(1.0, gt=0.0, description="mean duration of a satellite fault (h): the exposure of an "
                                                      "approach adds T_EXP/MFD to the prior")
    mfd_const_h: float = Field(1.0, gt=0.0, description="mean duration of a constellation fault (h)")

    @model_validator(mode="after")
    def _ure_below_ura(self):
        if self.sigma_ure_m > self.sigma_ura_m:
            raise ValueError(f"sigma_ure_m = {self.sigma_ure_m} exceeds sigma_ura_m = {self.sigma_ura_m}: the "
                             "accuracy sigma is expected at most the integrity overbound")
        return self


def ism_preset(name: Literal["wgc_lpv200", "icao2024_draft"]) -> dict[str, ConstellationIsm]:
    """A named ISM, per system.

    ``wgc_lpv200``: σ_URA 0.75 m, σ_URE 0.50 m, b_nom 0.50 m, P_sat 1e-5, P_const 1e-4 for every system, the
    LPV-200 example of the ARAIM Airborne Design Document v3.1, Appendix D (BeiDou and GLONASS given the same
    figures by assumption: no public ISM of theirs was found). ``icao2024_draft``: the example MAAST-2 ships as
    based on the June 2024 draft of ICAO Annex 10's default ISD (GPS σ_URA 2.4 m, P_const 1e-8; Galileo 6 m;
    GLONASS 9 m), an H-ARAIM oriented set under which LPV-200 is rarely available.
    """
    if name == "wgc_lpv200":
        return {s: ConstellationIsm() for s in SYSTEMS}
    if name == "icao2024_draft":
        return {
            "GPS": ConstellationIsm(sigma_ura_m=2.4, sigma_ure_m=2.4, b_nom_m=0.0, p_sat=1e-5, p_const=1e-8),
            "Galileo": ConstellationIsm(sigma_ura_m=6.0, sigma_ure_m=4.0, b_nom_m=0.0, p_sat=3e-5, p_const=2e-4,
                                        mfd_sat_h=1.5, mfd_const_h=2.0),
            "GLONASS": ConstellationIsm(sigma_ura_m=9.0, sigma_ure_m=8.0, b_nom_m=0.0, p_sat=1.02e-4, p_const=1e-4,
                                        mfd_sat_h=3.0, mfd_const_h=10.0),
        }
    raise ValueError(f"ISM preset: expected 'wgc_lpv200' or 'icao2024_draft', got {name!r}")


class AidFaultPrior(StrictModel):
    """The fault prior of a non-GNSS fault event (one landmark, the whole camera): docs/design/araim.md §11."""

    p: float = Field(ge=0.0, lt=1.0, description="prior probability of the fault at any instant")
    mfd_h: float = Field(1.0, gt=0.0, description="mean duration of the fault (h): the exposure of an approach adds "
                                                  "T_EXP/MFD to the prior")


class AraimSettings(StrictModel):
    """Risk allocation, exposure model and solver tolerance of the ARAIM monitor (docs/design/araim.md)."""

    ism: dict[str, ConstellationIsm] = Field(default_factory=lambda: ism_preset("wgc_lpv200"),
                                             description=f"integrity support data per system (some of {SYSTEMS})")
    user_error: UserErrorModel = Field(
        "wgc_m3", description="airborne multipath + noise curve σ_user (docs/design/araim.md eq. 2-4)")
    tropo_zenith_m: float = Field(0.12, gt=0.0, description="residual troposphere σ at zenith (m)")
    p_hmi_vert: float = Field(9.8e-8, gt=0.0, lt=1.0, description="integrity budget of the vertical (per approach)")
    p_hmi_hor: float = Field(2e-9, gt=0.0, lt=1.0, description="integrity budget of the horizontal (per approach)")
    p_fa_vert: float = Field(3.9e-6, gt=0.0, lt=1.0, description="false-alert budget of the vertical tests")
    p_fa_hor: float = Field(9e-8, gt=0.0, lt=1.0, description="false-alert budget of the horizontal tests")
    p_thres: float = Field(8e-8, gt=0.0, lt=1.0, description="the largest prior left unmonitored")
    p_emt: float = Field(1e-5, gt=0.0, lt=1.0, description="EMT = the largest vertical threshold of the modes whose "
                                                           "prior is at least this")
    tol_pl: float = Field(0.05, gt=0.0, le=10.0, description="protection level tolerance (m): the half-interval "
                                                             "search stops when the bracket is this narrow and "
                                                             "returns its upper end")
    t_exp_s: float = Field(150.0, ge=0.0, description="exposure time of an approach (s): a fault present at any "
                                                      "time in it counts (prior × (1 + T_EXP/MFD)); 0 = none")
    n_es_int: int = Field(25, ge=1, description="effective independent samples over the exposure, integrity")
    n_es_cont: int = Field(25, ge=1, description="effective independent samples over the exposure, continuity "
                                                 "(divides P_FA)")
    max_pmd: bool = Field(True, description="cap each fault mode's missed-detection probability at "
                                            "p_exp/(p·N_ES_INT) (else p_exp/p)")
    fc_thres: float = Field(0.01, ge=0.0, lt=1.0, description="fault consolidation: a mode inside one constellation "
                                                              "whose prior is below fc_thres × that constellation's "
                                                              "is folded into the constellation mode; 0 = off")
    min_fault_order: int = Field(1, ge=1, le=4, description="monitor combinations of at least this many fault "
                                                            "events even when the ADD rule asks for fewer")
    max_fault_order: int = Field(3, ge=1, le=4, description="the largest combination of fault events enumerated; "
                                                            "an epoch that needs more is unavailable (its reason "
                                                            "says so)")
    max_cond: float = Field(1e10, gt=1.0, description="largest accepted 1-norm condition number of a subset's "
                                                      "Jacobi-scaled normal matrix; above it the subset is "
                                                      "unobservable")
    service_levels: tuple[str, ...] = Field(("LPV-200", "APV-I", "APV-II"),
                                            description="levels whose availability is reported, in this order")
    landmark: AidFaultPrior = Field(AidFaultPrior(p=1e-5), description="fault prior of one landmark's pixels (a "
                                                                       "mis-detection, a moved or mis-surveyed "
                                                                       "landmark), each landmark independent; read "
                                                                       "with vision rows only (docs/design/araim.md "
                                                                       "§11)")
    camera: AidFaultPrior = Field(AidFaultPrior(p=1e-4), description="fault prior of the whole camera (dithering or "
                                                                     "an attitude error beyond their sigmas, a "
                                                                     "mis-registered map, a calibration fault); "
                                                                     "read with vision rows only")
    inertia: AidFaultPrior = Field(AidFaultPrior(p=1e-5), description="fault prior of an inertial position "
                                                                      "prediction given as rows (an IMU fault, a "
                                                                      "wrong alignment): docs/design/araim.md §11")

    @field_validator("ism")
    @classmethod
    def _known_systems(cls, v: dict[str, ConstellationIsm]) -> dict[str, ConstellationIsm]:
        unknown = [s for s in v if s not in SYSTEMS]
        if unknown:
            raise ValueError(f"unknown system(s) {unknown}; expected some of {list(SYSTEMS)}")
        if not v:
            raise ValueError(f"expected the ISM of at least one system of {list(SYSTEMS)}")
        return v

    @field_validator("service_levels")
    @classmethod
    def _known_levels(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        unknown = [s for s in v if s not in SERVICE_LEVELS]
        if not v or unknown:
            raise ValueError(f"expected some of {list(SERVICE_LEVELS)}, got {list(v)}")
        return v

    @model_validator(mode="after")
    def _orders(self):
        if self.min_fault_order > self.max_fault_order:
            raise ValueError(f"min_fault_order = {self.min_fault_order} exceeds max_fault_order = "
                             f"{self.max_fault_order}")
        return self

    @classmethod
    def add_v31(cls, **changes) -> "AraimSettings":
        """The ADD v3.1 allocation as its Appendix D example runs it: no exposure (T_EXP = 0), one effective
        sample (N_ES = 1), no fault consolidation, no cap on the missed detection."""
        base = dict(t_exp_s=0.0, n_es_int=1, n_es_cont=1, max_pmd=False, fc_thres=0.0)
        return cls(**(base | changes))

    def exposure_factor(self, mfd_h: float) -> float:
        """A fault prior's growth over the exposure (eq. 5): a fault present at any time in it counts,
        ``1 + T_EXP/MFD``."""
        return 1.0 + self.t_exp_s / (3600.0 * mfd_h)

    def system_ism(self, system: int) -> ConstellationIsm:
        """The ISM of system code ``system`` (an index into :data:`SYSTEMS`)."""
        name = SYSTEMS[system]
        if name not in self.ism:
            raise ValueError(f"ARAIM: a row of system {name!r} but the ISM has only {list(self.ism)}")
        return self.ism[name]


class AraimMonitorSettings(AraimSettings):
    """The options of the ``araim`` monitor (``[monitor.araim]`` in an approach file): the allocation and ISM of
    :class:`AraimSettings`, the ISM preset they start from, and fault exclusion.

    The service levels are the run's (``[integrity] service_levels``), so every monitor of a run reports
    availability for the same levels; LPV-200's availability adds the EMT and σ_acc,v criteria.
    """

    ism_preset: Literal["wgc_lpv200", "icao2024_draft"] = Field(
        "wgc_lpv200", description="the integrity support data the monitor starts from (docs/design/araim.md §1); "
                                  "entries of ``ism`` replace a system's whole ISM")
    fde: bool = Field(False, description="exclusion after a failed solution-separation test: re-solve without each "
                                         "used satellite (then pairs, with fde_max_excluded = 2) and keep the one "
                                         "whose own tests pass; the protection levels after an exclusion are the "
                                         "reduced geometry's with the integrity budget shared among the candidates")
    fde_rule: Literal["best", "unique"] = Field(
        "best", description="which passing exclusion is taken: 'best' = the smallest largest normalised separation; "
                            "'unique' = only when exactly one passes")
    fde_max_excluded: int = Field(1, ge=1, le=2, description="satellites one exclusion may remove")
    vision: bool = Field(False, description="landmark pixels as ARAIM rows with their own fault modes (one per "
                                            "landmark, prior ``landmark``; one for the camera, prior ``camera``), "
                                            "the camera's attitude-reference and dithering rotations as states "
                                            "with prior rows (docs/design/araim.md §11); the monitor then reads "
                                            "the camera, which the run synthesises for it")
    max_landmarks: int = Field(6, ge=1, le=30, description="with ``vision``: at most this many detected landmarks "
                                                          "an epoch, spread over the image (each adds two rows "
                                                          "and a fault event)")
    sigma_px: float | None = Field(None, gt=0.0, description="with ``vision``: the pixel sigma (px, per axis) the "
                                                             "rows are weighted with; unset = the sigma the vision "
                                                             "front end reports with each detection")

    @model_validator(mode="before")
    @classmethod
    def _preset_then_overrides(cls, data):
        if isinstance(data, dict):
            if "service_levels" in data:
                raise ValueError("service_levels: the araim monitor reports the run's [integrity] service_levels "
                                 f"(got {data['service_levels']!r} here); set them there")
            preset = data.get("ism_preset", "wgc_lpv200")
            if preset in ("wgc_lpv200", "icao2024_draft"):  # else the field's own error names it
                data = {**data, "ism": {**ism_preset(preset), **dict(data.get("ism") or {})}}
        return data

    @model_validator(mode="after")
    def _read_options_only(self):
        """Options the monitor would not read are refused, not ignored: the vision ones without ``vision``, and
        ``inertia`` (the monitor feeds no inertial prediction: docs/design/araim.md §11)."""
        set_ = self.model_fields_set
        unread = [k for k in ("max_landmarks", "sigma_px", "landmark", "camera") if k in set_] if not self.vision else []
        if unread:
            raise ValueError(f"{', '.join(unread)} read only with vision = true (got vision = false)")
        if "inertia" in set_:
            raise ValueError("inertia: the araim monitor feeds no inertial prediction, so its prior is not read (the "
                             "GNSS/vision/INS filter's [monitor.ekf] pl_variant = 'araim' puts the IMU in ARAIM's "
                             "budget: docs/design/nav-filter.md §8.4)")
        return self

    def allocation(self, service_levels: tuple[str, ...]) -> AraimSettings:
        """The :class:`AraimSettings` these options hold, reporting ``service_levels`` (the run's)."""
        return AraimSettings(**{k: getattr(self, k) for k in AraimSettings.model_fields if k != "service_levels"},
                             service_levels=service_levels)
