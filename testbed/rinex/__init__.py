"""Recorded data in: RINEX observation files to monitor-ready GPS observations, and ``testbed monitor``.

Public entry points::

    from testbed.rinex import monitor_rinex, read_obs, form_epochs, RinexSettings
"""

from testbed.rinex.obs import RinexObs, read_obs
from testbed.rinex.observables import Formation, form_epochs
from testbed.rinex.run import RinexRun, monitor_rinex, print_summary
from testbed.rinex.settings import MonitorFileConfig, RinexSettings

__all__ = ["Formation", "MonitorFileConfig", "RinexObs", "RinexRun", "RinexSettings", "form_epochs", "monitor_rinex",
           "print_summary", "read_obs"]
