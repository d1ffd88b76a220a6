"""Message schema of the roles family (Chapter 6), in the form of :mod:`copath.wire.payloads`."""

from __future__ import annotations

__all__ = ["MESSAGE_KIND", "PAYLOADS", "CONSENSUS", "ASSIGNED", "UNASSIGNED"]

MESSAGE_KIND = "role_state"
"""Kind of the task-tagged state broadcast of every robot of a Chapter 6 team."""

CONSENSUS, ASSIGNED, UNASSIGNED = 0, 1, 2
"""Phases of the assignment: agreeing on the transform; holding a position; without a position."""

PAYLOADS = {
    # Ch. 6 roles: task-tagged state broadcast; moment consensus with edge flows
    # (Algorithm 6.1), (6.16) z/eta, claim/taken sets and rulings [pos, winner, loser] (Alg. 6.2);
    # claims {robot: [pos, stamp, on it]} and tombstones gone {robot: stamp} of lost robots
    # (docs/reference/ambiguities.md, robot lost in role assignment (A38)).
    MESSAGE_KIND: {"task": "int", "index": "int", "phase": "int", "pos": "floats", "vel": "floats", "deg": "int",
                   "z": "float", "eta": "float", "claim": "int", "d": "float", "taken": "ints", "park": "floats",
                   "rulings": "any", "ac_x?": "floats", "ac_to?": "strs", "ac_a?": "floats", "ac_e?": "floats",
                   "ac_deg?": "int", "known?": "any", "xf?": "floats", "zdot?": "float", "etadot?": "float",
                   "claims?": "any", "gone?": "any"},
}
