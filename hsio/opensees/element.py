"""One genericClient element served: its messages answered from the lab (docs/opensees.md).

Basic DOF i of the genericClient is basic DOF i of the served element, in the order of its
``dofs`` (one DOF: the actuator's; several: through its setup, docs/setups.md). Units are
converted at this boundary (:meth:`hsio.opensees.lab.Lab.to_mm` and the like): translations
times ``length_factor`` give mm, rotations are radians on both sides; basic forces and matrices
go back in the model's units. Matrices go out column-major.
"""

from __future__ import annotations

import numpy as np

from hsio.opensees import protocol as p
from hsio.opensees.lab import Lab

MAX_MESSAGES = 1_000_000_000  # per connection: each message is also bounded by the idle timeout
MAX_STOPPED_MESSAGES = 10_000_000  # per connection after its session stopped: then it is closed


class SessionEnded(Exception):
    """Another element stopped the session, and this element was detached from it."""


class ElementHandler:
    """Answers one connected element ``j`` of ``lab``; :meth:`serve` runs until it leaves."""

    def __init__(self, lab: Lab, j: int, framer: p.Framer, ctrl=(1, 1, 1, 0, 1), ended=lambda: ""):
        self.lab = lab
        self.ended = ended  # why another element stopped the session and detached this one ('' while it goes on)
        self.action: int | None = None  # the action being answered (None between messages, or when unknown)
        # which signals a trial carries (the setup's sizeCtrl; a signal of size 0 takes no slot)
        self.has_vel, self.has_accel, self.has_time = bool(ctrl[1]), bool(ctrl[2]), bool(ctrl[4])
        self.j = j
        self.name = lab.names[j]
        self.framer = framer
        self.n = lab.n_basic[j]
        self.messages = 0
        self.died = False  # the element ended with DIE

    def serve(self) -> str:
        """Messages until DIE (returns why it ended); raises ProtocolError, PeerClosed, OSError,
        HsioError."""
        for _ in range(MAX_MESSAGES):
            self.action = None
            frame = self.framer.receive()
            self.messages += 1
            where = f"element {self.name}, message {self.messages}"
            action = p.action_of(frame, where)
            if action == p.DIE:
                self.died = True
                return "DIE received"
            self.action = action
            why = self.ended()
            if why:
                raise SessionEnded(why)
            reply = self.answer(action, frame, where)
            if reply is not None:
                self.framer.send(reply)
        self.action = None
        return f"{MAX_MESSAGES} messages"

    def answer(self, action: int, frame: np.ndarray, where: str):
        lab, j, n = self.lab, self.j, self.n
        if action == p.SET_TRIAL:
            trial = p.Trial.from_frame(frame, n, where, self.has_time, self.has_vel, self.has_accel)
            lab.set_trial(j, trial)
            return None
        if action == p.COMMIT:
            lab.commit(j)
            lab.wait_for_step(j, lab.settings.timeout_s)
            return None
        if action == p.GET_FORCE:
            return lab.force_to_model(j, lab.force(j))
        if action == p.GET_DISP:
            return lab.to_model(j, lab.displacement(j))
        if action == p.GET_TIME:
            return np.array([lab.latest_time(j)])
        if action in (p.GET_INITIAL_STIFF, p.GET_TANGENT_STIFF):
            K = lab.K_EI[j] if action == p.GET_INITIAL_STIFF else lab.tangent(j)
            return p.matrix_payload(lab.stiffness_to_model(j, K))
        if action == p.GET_DAMP:  # kN s/mm -> model (time in s)
            return p.matrix_payload(lab.stiffness_to_model(j, lab.matrix(j, "damping")))
        if action == p.GET_MASS:  # kN s^2/mm -> model
            return p.matrix_payload(lab.stiffness_to_model(j, lab.matrix(j, "mass")))
        raise p.ProtocolError(f"{where}: action {action} is not served")


class StoppedElement:
    """A client whose session stopped on a fault (docs/opensees.md, "A session that stops"): its
    connection stays open, and nothing it sends reaches the actuators again. Each request is
    answered with NaN in the slots of its reply (n forces or displacements, an n x n matrix, one
    time), so that the model's state turns non-finite and its analysis ends by itself (an
    OpenSees genericClient whose connection is closed reads the closed socket for ever). The
    connection closes on DIE, when the client closes it, after ``timeout_s`` of silence or after
    :data:`MAX_STOPPED_MESSAGES` messages."""

    def __init__(self, framer: p.Framer, n: int, name: str):
        self.framer = framer
        self.n = n
        self.name = name
        self.answered = 0  # requests answered with NaN
        self.messages = 0
        self.died = False

    def reply(self, action: int) -> np.ndarray:
        """NaN in the slots that ``action``'s reply fills."""
        size = 1 if action == p.GET_TIME else self.n if action in (p.GET_FORCE, p.GET_DISP) else self.n * self.n
        return np.full(size, np.nan)

    def serve(self, pending: int | None = None) -> str:
        """Answer ``pending`` (the request the fault interrupted, if it wants a reply), then every
        later message until the client leaves (returns why); raises PeerClosed, TimeoutError,
        OSError, ProtocolError (an action this server cannot tell the reply of)."""
        if pending in p.REPLIES:
            self.framer.send(self.reply(pending))
            self.answered += 1
        for _ in range(MAX_STOPPED_MESSAGES):
            frame = self.framer.receive()
            self.messages += 1
            action = p.action_of(frame, f"element {self.name}, message {self.messages} after the stop")
            if action == p.DIE:
                self.died = True
                return "DIE received"
            if action in p.REPLIES:
                self.framer.send(self.reply(action))
                self.answered += 1
        return f"{MAX_STOPPED_MESSAGES} messages after the stop"
