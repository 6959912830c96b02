"""The sim node's side of a cutting job: the job runner's controller is the drive and the wire.

:class:`JobDrive` is what :func:`ladrc_sim.job.runner.run_job` steps when the sim node plays a
job (``-p job:=NAME``), as the :class:`~.drive_bridge.DriveBridge` is what the scenario runner
steps: per tick it sends the CNC's motion sample of the tick on ``cnc/motion`` (when the CNC
cycle has one), has the bridge publish the tick's samples and return the drive's command, and
gives the CNC the controller's answers from ``follow/status`` (:class:`~.follow_link.FollowLink`:
the fields the CNC reads are all in it, docs/interfaces.md "CNC interface"). The CNC's commands
go to the follow services.

Live: the CNC reads the newest status that arrived (a CNC's cycle lags the controller's), and
its commands are sent without waiting (a refusal, when its answer comes, aborts the job, as a
refusal does headless). Lock step: the sim waits for the status answering step k before the CNC
steps k + 1, and each command's answer before the step's samples go out: the headless runner's
order, so a lock-step job equals the headless job bit for bit (tests/ros/test_lockstep.py).

With a separate CNC (``remote_cnc``: the CNC node plays it, :mod:`.remote_cnc`) the CNC's
samples and commands are the CNC node's: this drive only steps the axis and reads the answers
(the job's series keep the controller's state).
"""

from __future__ import annotations

from typing import Any

from ladrc_contract.tick import CncInput, TickInput

from .follow_link import FollowLink


class JobDrive:
    """The job runner's controller in the sim node (module docstring)."""

    def __init__(self, node: Any, bridge: Any, remote_cnc: bool = False) -> None:
        """``node``: the sim node (its CNC publisher, status reader, follow clients)."""
        self.node = node
        self.bridge = bridge
        self.lockstep = bridge.lockstep
        self.remote_cnc = remote_cnc
        self.link = FollowLink(node, self.lockstep, bridge._await)
        self._x_mm = self._y_mm = float('nan')
        self._cnc: CncInput | None = None  # the CNC's newest sample, not sent yet

    # ---- the job runner's hooks ---------------------------------------------------------
    def truth(self, t_s: float, true_gap_mm: float, sheet_mm: float, nozzle_mm: float,
              coverage: float, plate_velocity_mm_s: float, x_mm: float, y_mm: float) -> None:
        """Truth of the coming tick, the nozzle's XY included (``sim/truth``)."""
        self._x_mm, self._y_mm = x_mm, y_mm
        self.bridge.truth(t_s, true_gap_mm, sheet_mm, nozzle_mm, coverage, plate_velocity_mm_s,
                          x_mm, y_mm)

    def quick_stop(self) -> bool:
        """Return True while the drive brakes (watchdog or commander fault)."""
        return self.bridge.quick_stop()

    def step(self, tick: TickInput, cnc: CncInput | None) -> float:
        """Send the CNC's sample, step the drive; lock step: wait for the step's status.

        Live, a cycle the drive catches up silently (its process was late) sends nothing:
        the CNC's newest sample goes out with the next cycle that publishes, and the status
        is read then (a silent cycle must cost as little as it can, or catching up takes
        longer than the controller's stale-input limit allows).
        """
        if cnc is not None and not self.remote_cnc:
            self._cnc = cnc
        silent = self.bridge.will_be_silent()
        if self._cnc is not None and not silent:
            self.node.publish_cnc(self._cnc, self._x_mm, self._y_mm)
            self._cnc = None
        velocity = self.bridge.step(tick)
        if self.lockstep:
            self.link.await_status(self.bridge.seq - 1)
        elif not silent:
            self.link.take_status()
        return velocity

    def internals(self) -> dict[str, Any]:
        """Return the controller's answers: its newest ``FollowStatus`` (``ANSWERS``)."""
        return self.link.answers

    def command(self, name: str, **kwargs: Any) -> tuple[bool, str]:
        """Send a CNC command to the follow service; lock step: return its answer."""
        return self.link.command(name, **kwargs)

    def refusals(self) -> list[tuple[str, str]]:
        """Live: return the commands refused since the last call, as (name, message)."""
        return self.link.refusals()
