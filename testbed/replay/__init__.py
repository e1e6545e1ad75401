"""Monitoring recorded data: a receiver's RINEX observation and navigation files stepped through the same monitors
as a flight (:func:`monitor_rinex`), with its tables, Stanford diagrams and recording. Reading and forming the
observations is :mod:`testbed.rinex`'s.

Public entry points::

    from testbed.replay import monitor_rinex, print_summary, RinexRun
"""

from testbed.replay.run import RinexRun, monitor_rinex, print_summary

__all__ = ["RinexRun", "monitor_rinex", "print_summary"]
