"""Plug-in pilots that fail on purpose, for the tests of failed cells (named `fault_pilots:RaisingPilot` etc.;
importable in spawned worker processes and Ray workers, which get this folder on their path).

Each flies like the potential-field pilot unless its fault is armed: a file named after the fault (`raise`,
`exit`, `kill`, `hang`) in the folder named by the environment variable FAULT_DIR (worker processes
inherit it). The fault goes off at the pilot's first decision after ARMED_AFTER_S of flight. An armed
fault fires once: the first cell that takes its file away fails, the next cell of that pilot flies (so a
replaced worker is seen flying on, and a resumed run succeeds).
"""
from __future__ import annotations

import os
import signal
import time
from pathlib import Path

from rl.pilots.potential_field import PotentialFieldPilot
from uam_fdm.pilot import Actuation, Observation

ARMED_AFTER_S = 0.2


class FaultInjected(RuntimeError):
    """What RaisingPilot raises."""


def take(fault: str) -> bool:
    """The fault `fault` is armed, and this cell takes it (removes its file; only one cell can)."""
    folder = os.environ.get("FAULT_DIR")
    if not folder:
        return False
    try:
        (Path(folder) / fault).unlink()
    except FileNotFoundError:
        return False
    return True


class _FaultyPilot(PotentialFieldPilot):
    fault = ""
    wall_s_per_flight_s = 0.2

    def reset(self, world, task, seed):
        self._fires = take(self.fault)
        return super().reset(world, task, seed)

    def act(self, obs: Observation) -> Actuation:
        if self._fires and obs.t_s >= ARMED_AFTER_S:
            self.go_off()
        return super().act(obs)

    def go_off(self) -> None:
        raise NotImplementedError


class RaisingPilot(_FaultyPilot):
    """Raises FaultInjected in act."""

    fault = "raise"

    def go_off(self) -> None:
        raise FaultInjected("injected fault in act")


class ExitingPilot(_FaultyPilot):
    """Ends its process at once with exit code 3 (as a native crash would, no Python cleanup)."""

    fault = "exit"

    def go_off(self) -> None:
        os._exit(3)


class KilledPilot(_FaultyPilot):
    """Sends SIGKILL to its own process (as the out-of-memory killer would)."""

    fault = "kill"

    def go_off(self) -> None:
        os.kill(os.getpid(), signal.SIGKILL)


class HangingPilot(_FaultyPilot):
    """Sleeps for an hour in act."""

    fault = "hang"

    def go_off(self) -> None:
        time.sleep(3600.0)
