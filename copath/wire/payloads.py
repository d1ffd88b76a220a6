"""Payload schemas of robot-to-robot messages, keyed by message kind.

Each entry maps a field name to its type: ``float``, ``int``, ``bool``, ``str``,
``floats`` (list of numbers), ``ints``, ``points`` (list of [x, y]) or ``any``. A name
ending in ``?`` is optional. Receivers validate every payload against this table
(``copath.wire.messages.validate_payload``) and count what they reject; bump
``copath.wire.messages.WIRE_VERSION`` (carried by every record) when a field changes meaning.
"""

from __future__ import annotations

PAYLOADS: dict[str, dict[str, str]] = {
    # Sec. 5.5: path coordinate and virtual-vehicle speed, (5.42); receivers
    # extrapolate s by sdot times the message age; s_d is the sender's desired
    # offset, so s_dij = s_di - s_dj needs no global table; sddot is the sender's
    # acceleration, for a second-order prediction over the message age.
    "coord_state": {"s": "float", "sdot": "float", "s_d": "float", "sddot?": "float"},
    # Sec. 5.3: leader broadcast after each solve.
    "leader_plan": {"s_l": "float", "sdot_pred": "floats", "delta_l": "float", "slowdown?": "float"},
    # Sec. 5.3 extension (formation feedback): follower -> leader tracking error.
    "follower_status": {"tracking_error": "float"},
    # Sec. 5.4, Algorithm 5.1: assumed trajectory s_hat on the grid t0 + k dt.
    "assumed_traj": {"t0": "float", "dt": "float", "s_hat": "floats", "psi_scale?": "float"},
    # Sec. 5.5.5: leader -> follower velocity command; follower -> leader report.
    # The command carries the follower's reference pose and coordination coordinate
    # computed on the leader (for the follower's telemetry); the report is the follower's
    # pose estimate (the leader's camera fix plus compass heading in the original).
    "hetero_cmd": {"v": "float", "omega": "float", "ref?": "floats", "xi?": "float"},
    "hetero_report": {"x": "float", "y": "float", "heading": "float"},
    # Ch. 6 roles: task-tagged state broadcast; moment consensus with edge flows
    # (Algorithm 6.1), (6.16) z/eta, claim/taken sets and rulings [pos, winner, loser] (Alg. 6.2);
    # claims {robot: [pos, stamp, on it]} and tombstones gone {robot: stamp} of lost robots
    # (docs/reference/ambiguities.md, robot lost in role assignment (A38)).
    "role_state": {"task": "int", "index": "int", "phase": "int", "pos": "floats", "vel": "floats", "deg": "int",
                   "z": "float", "eta": "float", "claim": "int", "d": "float", "taken": "ints", "park": "floats",
                   "rulings": "any", "ac_x?": "floats", "ac_to?": "strs", "ac_a?": "floats", "ac_e?": "floats", "ac_deg?": "int",
                   "known?": "any", "xf?": "floats", "zdot?": "float", "etadot?": "float",
                   "claims?": "any", "gone?": "any"},
    # E6.6: coordination coordinate xi = s - s_d, its rate, and the formation index.
    "formation_state": {"xi": "float", "xidot": "float", "formation": "int", "index": "int", "xiddot?": "float"},
}
