"""GNSS sensor: almanac & orbits, error models, clocks, visibility, pseudoranges, RINEX export.

Public entry points::

    from testbed.sensors.gnss import GnssSettings, synthesize_gnss, gnss_geometry, sample_gnss, write_rinex
"""

from testbed.sensors.gnss.almanac import load_constellation, load_do229, load_rinex_nav, load_yuma
from testbed.sensors.gnss.errors import IONO_FREE_FACTOR, sigma_pseudorange
from testbed.sensors.gnss.orbits import Ephemeris, sat_states
from testbed.sensors.gnss.rinex import read_rtklib_pos, rtklib_single_point, write_nav, write_rinex
from testbed.sensors.gnss.settings import GnssSettings
from testbed.sensors.gnss.synth import GnssGeometry, gnss_geometry, sample_gnss, synthesize_gnss
from testbed.sensors.gnss.timebase import utc_to_gps_seconds

__all__ = ["Ephemeris", "GnssGeometry", "GnssSettings", "IONO_FREE_FACTOR", "gnss_geometry", "load_constellation",
           "load_do229", "load_rinex_nav", "load_yuma", "read_rtklib_pos", "rtklib_single_point", "sample_gnss",
           "sat_states", "sigma_pseudorange", "synthesize_gnss", "utc_to_gps_seconds", "write_nav", "write_rinex"]
