"""Sim-to-real gap diagnosis (issue 8): where the gap lies, which unmodelled effect, how far
it shrinks. Observer layer built; display and render layers not yet built."""

from analysis.gap.diagnose import diagnose_observer, diagnose_observer_files
from analysis.gap.engine import Candidate, CandidateScore, Diagnosis, GapError, holm
from analysis.gap.observer import OBSERVER_CANDIDATES, load_sessions, localise_observer

__all__ = [
           "OBSERVER_CANDIDATES",
           "Candidate",
           "CandidateScore",
           "Diagnosis",
           "GapError",
           "diagnose_observer",
           "diagnose_observer_files",
           "holm",
           "load_sessions",
           "localise_observer",
]
