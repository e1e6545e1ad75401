"""Recorded data in: RINEX observation files read and formed into monitor-ready GPS observations. Stepping the
monitors over them (``testbed monitor``) is :mod:`testbed.replay`'s.

Public entry points::

    from testbed.rinex import read_obs, form_epochs, RinexSettings
"""

from testbed.rinex.obs import RinexObs, read_obs
from testbed.rinex.observables import Formation, form_epochs
from testbed.rinex.settings import MonitorFileConfig, RinexSettings

__all__ = ["Formation", "MonitorFileConfig", "RinexObs", "RinexSettings", "form_epochs", "read_obs"]
