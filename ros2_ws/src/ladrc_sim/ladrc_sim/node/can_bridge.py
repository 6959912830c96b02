"""The sim node's drive on a CAN bus: the emulated CiA 402 drive (``-p drive:=cia402``).

The sim node plays its scenario or job as always (the same runner, the follow commands as
service calls, ``sim/truth``, a job's CNC); only the drive differs: instead of publishing
``axis/feedback`` and ``axis/capacitive_height`` and taking ``axis/velocity_command`` on ROS
(:class:`~.drive_bridge.DriveBridge`), the runner steps a
:class:`~ladrc_sim.cia402.can_drive.CanDrive`, a CANopen node on the bus that a driver node (the
machine's, ``ladrc_cia402 driver_node``) masters. The drive's samples reach the controller
through that driver; the commander lock and the drive watchdog are the driver's and the drive's
(its RPDO deadline).

Lock step: the drive advances one period per SYNC; this node publishes ``sim/lockstep`` k (the
samples k the driver publishes: its ``seq`` counts one pair per SYNC) and the truth of step k as
sample k's TPDOs go out.
"""

from __future__ import annotations

from typing import Any

from ..cia402.can_drive import CanDrive, StopDrive
from ..cia402.can_drive import LockstepAbort as CanAbort
from .drive_bridge import DriveBridge, LockstepAbort, StopSimulation


class CanDriveBridge(DriveBridge):
    """The runner's controller of the sim node when its drive is on a CAN bus."""

    def __init__(self, node: Any, drive: CanDrive, realtime: bool = True) -> None:
        """``drive``: the emulated drive, its ``lockstep`` as the node's."""
        self.drive = drive
        super().__init__(node, realtime)
        drive.on_sample = self._on_sample

    @property
    def running(self) -> bool:  # type: ignore[override]
        """False once the node is asked to stop (the drive's waits end too)."""
        return self.drive.running

    @running.setter
    def running(self, value: bool) -> None:
        self.drive.running = value

    def take_commands(self) -> None:
        """Take nothing: the commands are the driver's (on the bus), not on ROS."""

    def will_be_silent(self) -> bool:
        """Return False: the drive keeps its own clock, no cycle is caught up silently."""
        return False

    def drive_event(self, **args: Any) -> None:
        """Pass a scenario's ``drive`` event, with its error code, to the drive."""
        self.drive.drive_event(**args)

    def quick_stop(self) -> bool:
        """Return True while the CiA 402 drive is not in Operation enabled (the axis brakes)."""
        return self.drive.quick_stop()

    def step(self, tick: Any) -> float:
        """One drive period (:meth:`CanDrive.step`)."""
        self.last_tick = tick
        if self.t_start_ns == 0:
            self._start()
        try:
            velocity = self.drive.step(tick)
        except StopDrive:
            raise StopSimulation() from None
        except CanAbort as exc:
            raise LockstepAbort(str(exc)) from None
        self.seq = self.drive.seq
        self.cycles_by_commander[('cia402', self.drive.node_id)] += 1
        return velocity

    def _on_sample(self, k: int, tick: Any) -> None:
        """Sample k goes out on the bus: its step and truth on ROS."""
        self.seq = k
        self.node.publish_step_truth(k, tick, self.truth_values,
                                     stamp_ns=k * self.period_ns if self.lockstep else None)
