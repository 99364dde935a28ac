"""Planning: a safe, time-parametrised reference through the safe areas (paper Sec. III-C).

    SafeAreas + start + goal
      -> start / goal areas, goal projection, corridor (graph search)       corridor.py
      -> portal waypoints -> uniform arc-length interpolation (eq. 5-6)      corridor.py, smoothing.py
      -> cubic B-spline smoothing (eq. 7), kept inside the corridor          smoothing.py
      -> speed profile and samples at the MPC step dt                        timing.py
      -> Plan(corridor, goal, waypoints, path, smoothed, Reference)          reference.py

Entry point: :func:`plan` (:mod:`.pipeline`, which composes the stages). Configuration:
:class:`PlannerConfig`.
"""

from sanav_mj.planning.pipeline import PlannerConfig, plan, plan_document
from sanav_mj.planning.reference import Plan, Reference

__all__ = ["Plan", "PlannerConfig", "Reference", "plan", "plan_document"]
