"""Fuzz payloads: invalid records for a robot's keys, none of which may pass a receiver's
checks (docs/reference/faults.md)."""

from __future__ import annotations

import random

import msgpack

from copath.wire.messages import WIRE_VERSION, End, Obs, PeerEnvelope


def fuzz_payloads(rng: random.Random, n: int, victim: str, neighbour: str) -> list[bytes]:
    """``n`` invalid records for ``victim``'s keys: none may pass the receiver's checks."""
    coord = PeerEnvelope(neighbour, 1, 0.5, "coord_state", [0.0, 0.0], {"s": 0.1, "sdot": 0.2, "s_d": 0.0})
    good = [coord.to_dict(), Obs(1, 0.1, [0.0, 0.0, 0.0]).to_dict(), End(1, 0.1, "x").to_dict()]
    out = []
    for i in range(n):
        kind = i % 6
        if kind == 0:  # random bytes
            out.append(rng.randbytes(rng.randint(0, 300)))
        elif kind == 1:  # a valid record cut short
            data = coord.pack()
            out.append(data[: rng.randint(0, len(data) - 1)])
        elif kind == 2:  # oversized: a 200 kB string where a float belongs
            d = coord.to_dict()
            d["payload"] = {"s": "x" * 200_000, "sdot": 0.2, "s_d": 0.0}
            out.append(msgpack.packb(d))
        elif kind == 3:  # another wire version
            d = dict(rng.choice(good))
            d["v"] = rng.choice([0, WIRE_VERSION + 1, "1", None])
            out.append(msgpack.packb(d))
        elif kind == 4:  # well-formed forgery: somebody else's name
            d = coord.to_dict()
            d["sender"] = "intruder"
            out.append(msgpack.packb(d))
        else:  # well-formed forgery: a stamp from the far future, or not finite
            d = coord.to_dict()
            d["stamp"] = rng.choice([1e9, float("nan"), float("inf"), -1e9])
            out.append(msgpack.packb(d))
    return out
