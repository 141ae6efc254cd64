"""Apply: make a calibration its robot's active one, through the gate of app/services/safety.py.

A calibration belongs to the robot whose session it was made from (an instance: `nao-2`, not every NAO),
and is applied to that robot only: recorded in its apply history first, then pushed to its driver. One
that is worse than the active calibration or moves a parameter beyond its sane bound needs the operator's
confirmation (ConfirmationRequired, 409) unless `confirm`, and so does one whose solver did not converge.
Applying the active calibration again pushes it to the driver again (a robot that restarted) and adds no
history row.
"""

from __future__ import annotations

from typing import NotRequired, TypedDict

import numpy as np

from calib_core.estimation import register

from ..robots.roster import Robots
from ..store import Store
from . import safety


class Applied(TypedDict):
    """A calibration applied (the API's answer): `previous` None for the nominal model, `recorded` False when it
    was already active (pushed to the driver again, no history row), `deployed` what a driver that takes
    calibrations on the robot did with it (absent for the others)."""

    active: str
    previous: str | None
    robot: str
    recorded: bool
    deployed: NotRequired[str]


class ApplyService:
    def __init__(self, store: Store, robots: Robots) -> None:
        self.store = store
        self.robots = robots

    def apply(self, cal_id: str, note: str = "", *, confirm: bool = False) -> Applied:
        info = self.store.calibrations.info(cal_id)
        self.robots.get(info.robot)
        if not confirm:
            reasons = self.concerns(cal_id)
            if reasons:
                raise safety.ConfirmationRequired(
                    f"applying {cal_id} to {info.robot} needs confirmation: {reasons[0]}"
                    + (f" (and {len(reasons) - 1} more)" if len(reasons) > 1 else ""),
                    reasons,
                )
        deployed = self._deploy(info.robot, cal_id)
        if self.store.calibrations.active(info.robot) == cal_id:  # already active: pushed again, no new row
            self.robots.push_active(info.robot)
            answer = Applied(active=cal_id, previous=cal_id, robot=info.robot, recorded=False)
        else:
            if deployed is not None:
                note = f"{note} ({deployed})" if note else deployed
            active, previous = self.store.calibrations.apply(info.robot, cal_id, note)
            self.robots.push_active(info.robot)
            answer = Applied(active=active, previous=previous, robot=info.robot, recorded=True)
        if deployed is not None:
            answer["deployed"] = deployed
        return answer

    def _deploy(self, robot: str, cal_id: str) -> str | None:
        """A driver that takes calibrations on the robot itself (a ROS 2 robot's parameter) gets this one first:
        when that fails (RobotFault: refused, not answering) nothing is recorded and the active one stays. What it
        did, a sentence (None: a driver that takes nothing)."""
        driver = self.robots.get(robot).driver
        return None if driver is None else driver.deploy(cal_id, self.store.calibrations.load(cal_id))

    def concerns(self, cal_id: str) -> list[str]:
        """Why applying this calibration needs a confirmation (empty: it does not)."""
        info = self.store.calibrations.info(cal_id)
        profile = self.robots.get(info.robot).profile
        active_id, active_p = self.robots.active_params(info.robot)
        if active_id == cal_id:
            return []
        active = "the nominal model" if active_id is None else f"the active calibration {active_id}"
        cal = self.store.calibrations.load(cal_id)
        new_p = cal.params(profile)
        reasons = []
        if info.session_id is not None and self.store.sessions.exists(info.session_id):
            data = self.store.sessions.dataset(info.session_id, profile)
            heldout = np.isin(data.frame_ids, cal.frames.get("holdout", []))
            where = f"the held-out frames of session {info.session_id}"
            train = ~heldout
            if not heldout.any():
                heldout[:] = True
                where = f"the frames of session {info.session_id}"
            # An external tracker (if any) stood where this session's data say: the active parameters see it
            # through a registration fitted on the frames the candidate was fitted on.
            active_here = register(profile, data.select(train if train.any() else heldout), active_p)
            worse = safety.worse_than_active(profile, data.select(heldout), new_p, active_here, active, where)
            if worse is not None:
                reasons.append(worse)
        if not cal.converged:
            reasons.append(
                f"its solver did not converge ({cal.solver.status.value} after {cal.solver.iterations} iterations)"
            )
        reasons += safety.parameter_jumps(profile, new_p, active_p, active, from_nominal=active_id is None)
        return safety.concerns(reasons)
