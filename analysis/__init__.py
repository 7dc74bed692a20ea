"""Analysis: load sessions, figures, linear mixed models, image statistics, sim-to-real gap.

Public API
----------
matches_to_physical
"""

from analysis.units import matches_to_physical

__all__ = ["matches_to_physical"]
