"""The emulated rig's physics in step with the wire: due steps run while bytes are on the wire,
a state read waits for the steps due by its instant, and a still rig rests."""

from __future__ import annotations

import time

import numpy as np

from drivers.dynamixel.units import POSITION_MODES
from drivers.emulator.steady import run_steady
from drivers.servo.fast import PositionLoop

__all__ = ["PhysicsClock"]

#: Due physics steps a state read waits for (a few ms of the emulator's arithmetic at most): after
#: a hold-up of up to this many ms the answer is still the servos' state now, not as it was before
#: the hold-up (a slide at insertion speed is a tick off in well under 1 ms). A longer backlog means
#: the physics is not keeping real time, and it is then caught up after the answer.
_READ_WAITS_FOR_STEPS = 30
#: Present Position range (ticks) within which a servo counts as still: the hunt of a
#: holding servo is ±1 tick.
_STILL_TICKS = 3
#: Physics steps run between two looks at the port while the physics catches up: an instruction
#: that arrives meanwhile waits for at most this many steps (~0.1 ms each), not for the backlog.
SLICE_STEPS = 2


class PhysicsClock:
    """Part of :class:`~drivers.emulator.bus.DynamixelBusEmulator` (a mixin: it uses the bus's state)."""

    #: Run steady stretches for all servos at once (:mod:`drivers.emulator.steady`); False: servo by
    #: servo always (the reference the steady path is held to).
    steady = True

    def _due_steps(self, now: float) -> int:
        """Physics steps due by ``now``; beyond ``max_catchup_s`` the backlog is skipped."""
        if self._resting:
            self._sim_wall = max(self._sim_wall, now)  # nothing moves: no steps fall due
            return 0
        steps = int((now - self._sim_wall) / self.physics_dt)
        if steps <= 0:
            return 0
        limit = max(1, int(self.max_catchup_s / self.physics_dt))
        if steps > limit:
            self.stats.physics_skipped_s += (steps - limit) * self.physics_dt
            self._sim_wall += (steps - limit) * self.physics_dt
            steps = limit
        return steps

    def _catch_up(self, now: float) -> None:
        """Run the steps due by ``now``, a slice at a time; an instruction waiting on the port ends
        the catch-up (the rest stays due, for the next pass): after the process was held up (a
        loaded or slow machine), the backlog would otherwise keep the servos from answering."""
        steps = self._due_steps(now)
        if steps <= 0:
            return
        if self.max_batch_s is not None:  # the rest is due at the next pass
            steps = min(steps, max(1, int(self.max_batch_s / self.physics_dt)))
        self._run_physics(steps, yield_to_port=True)

    def _input_waiting(self) -> bool:
        """Whether bytes from the host wait to be read (the bus says; a bare clock never has any)."""
        return False

    def _catch_up_for_read(self, instant: float, from_steps: int = 1) -> None:
        """Run the steps due by a state read's ``instant`` where ``from_steps`` or more are, so its
        answer is at most that many steps old (unless the backlog is over
        :data:`_READ_WAITS_FOR_STEPS`: the physics is not keeping up)."""
        steps = self._due_steps(instant)
        if max(1, from_steps) <= steps <= _READ_WAITS_FOR_STEPS:
            self._run_physics(steps)

    def _catch_up_before(self, deadline: float) -> None:
        """Run the steps falling due by ``deadline``, one at a time, while each ends before it.

        No instruction can take effect before ``deadline`` (the wire is modelled
        busy, or a delayed status is still to go out), so a step may run ahead
        of its time: nothing it would have seen can change meanwhile.
        """
        while self._due_steps(deadline) and time.perf_counter() + self._step_cost <= deadline:
            self._run_physics(1)

    def _catch_up_between_instructions(self) -> None:
        """After a pass under the wire-time model: step in the wire's busy stretch only.

        The host's next instruction may come at any moment once the wire is idle,
        and a step then would delay its answer; so steps wait for a stretch where
        the wire is modelled busy, unless the physics would fall two steps behind.
        """
        self._catch_up_before(self._wire_free)
        now = time.perf_counter()
        if now - self._sim_wall >= 2 * self.physics_dt:
            self._catch_up(now)

    def _run_physics(self, steps: int, yield_to_port: bool = False) -> None:
        """Advance the physics by ``steps`` and update the estimate of one step's wall time; with
        ``yield_to_port``, :data:`SLICE_STEPS` at a time, stopping early for an instruction waiting
        on the port (the steps not run stay due)."""
        t0 = time.perf_counter()
        if yield_to_port:
            done = 0
            while done < steps:
                n = min(steps - done, SLICE_STEPS)
                self._physics(n)
                done += n
                if done < steps and self._input_waiting():
                    break
            steps = done
        else:
            self._physics(steps)
        self._sim_wall += steps * self.physics_dt
        self._step_costs.append((time.perf_counter() - t0) / steps)
        self._step_cost = 1.25 * sorted(self._step_costs)[len(self._step_costs) // 2]
        if self.rest_after_s is not None:
            self._watch_for_rest()

    def _watch_for_rest(self) -> None:
        """Pause the physics once every servo has stayed still for ``rest_after_s``."""
        ticks = np.fromiter((servo.get("Present Position") for servo, _ in self._servos),
                            float, len(self._servos))
        if self._still_lo is None or self._still_hi is None:
            self._still_lo, self._still_hi, self._still_since = ticks, ticks.copy(), self._sim_wall
            return
        np.minimum(self._still_lo, ticks, out=self._still_lo)
        np.maximum(self._still_hi, ticks, out=self._still_hi)
        if float(np.max(self._still_hi - self._still_lo)) > _STILL_TICKS:
            self._still_lo, self._still_hi, self._still_since = ticks, ticks.copy(), self._sim_wall
        elif self._sim_wall - self._still_since >= self.rest_after_s:
            if self._integrating():  # creeping to its goal slower than a tick a window: not at rest
                self._still_since = self._sim_wall
            else:
                self._resting, self._rest_since = True, time.perf_counter()

    def _integrating(self) -> bool:
        """Whether a servo's integrator is still charging: torque on in a position mode with an I
        gain, over a tick (or its deadband) from its goal. Its load's sag is still being taken up,
        a few ticks a second, and a rest would freeze it part way."""
        for servo, _ in self._servos:
            get = servo.get
            if (get("Torque Enable") == 1 and get("Operating Mode") in POSITION_MODES
                    and get("Position I Gain") > 0
                    and abs(get("Goal Position") - get("Present Position")) > max(1, servo.deadband_ticks)):
                return True
        return False

    def _wake(self) -> None:
        """A write instruction arrived: the physics resumes from now (the rest skipped no motion)."""
        self._still_lo = self._still_hi = None
        if self._resting:
            now = time.perf_counter()
            self._resting = False
            self.stats.rest_s += now - self._rest_since
            self._sim_wall = now

    _loop: PositionLoop | None = None

    def _position_loop(self) -> PositionLoop:
        """The servo array's position loop (fused where its plain case holds), made once."""
        if self._loop is None or self._loop.servos is not self._bank:
            self._loop = PositionLoop(self._bank, self.physics_dt)
        return self._loop

    def _physics(self, steps: int) -> None:
        dt = self.physics_dt
        plant = self.plant
        n = plant.joint_count
        bank, servos = self._bank, self._servos
        done = run_steady(servos, self._position_loop(), plant, steps) if self.steady else 0
        for _ in range(steps - done):
            q, v = plant.position().tolist(), plant.velocity().tolist()
            torque = [0.0] * n  # summed in Python floats: a servo's share is one addition, not a numpy item
            for servo, joint in servos:
                servo.begin_step(dt, q[joint], v[joint])
            bank.step_ticks(dt)
            for servo, joint in servos:
                torque[joint] += servo.end_step(dt)
            plant.step(dt, np.array(torque))
        q, v = plant.position(), plant.velocity()
        for servo, joint in self._servos:
            servo.observe(float(q[joint]), float(v[joint]))
        self.stats.physics_steps += steps
