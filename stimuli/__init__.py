"""Offline stimulus rendering: ellipsoid arrays, Ward BSDF, Mitsuba, tone mapping, gloss fitting.

Public API
----------
stimulus_set, SET_NAMES
"""

from stimuli.sets import SET_NAMES, stimulus_set

__all__ = ["SET_NAMES", "stimulus_set"]
