"""The PsychoPy session app: trial plans, sessions at the CRT, simulated observers.

Public API
----------
check_participant_id, make_plan, load_or_create_plan, plan_path, participant_seed, PLAN_COLUMNS
"""

from experiment.participants import check_participant_id
from experiment.plan import (
    PLAN_COLUMNS,
    PlanError,
    load_or_create_plan,
    make_plan,
    participant_seed,
    plan_path,
)

__all__ = [
    "PLAN_COLUMNS",
    "PlanError",
    "check_participant_id",
    "load_or_create_plan",
    "make_plan",
    "participant_seed",
    "plan_path",
]
