"""The studies: the source papers' experiments reproduced (VA-RAIM 2015, the DPE paper, Won et al. 2013), where
vision pays, what the pixel monitor adds, and the DPE's K calibration.

Each is an experiment *about* particular monitors, built on the campaign engine (:mod:`testbed.campaign`) and the
run pipeline; nothing in the engine depends on them.
"""
