"""Fault-injection Monte Carlo campaigns: specs, batched runner, resumable store, report figures.

>>> from testbed.campaign import load_spec, run_campaign, write_report
>>> run_campaign("approaches/campaigns/gps-step-sweep.toml", "out/gps-step")
>>> write_report("out/gps-step")
"""

from testbed.campaign.runner import CampaignResult, run_campaign
from testbed.campaign.spec import CampaignSpec, expand_cells, load_spec


def write_report(out_dir, **kw):
    from testbed.campaign.report import write_report as _w

    return _w(out_dir, **kw)


__all__ = ["CampaignResult", "CampaignSpec", "expand_cells", "load_spec", "run_campaign", "write_report"]
