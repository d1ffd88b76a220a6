"""Payload schemas of robot-to-robot messages: the table the wire validates against.

Each controller family declares the schemas of the kinds it sends on its factory
(:attr:`copath.control.ControllerFactory.payloads`, e.g. the consensus family's
``agent/controllers/consensus/payloads.py``); declaring the factory registers them here
(:func:`register_payloads`), so every process that has loaded a family validates that
family's payloads. A kind without a schema (a user controller's own) is checked as a map of
plain values with finite numbers.

A schema maps a field name to its type: ``float``, ``int``, ``bool``, ``str``, ``floats``
(list of numbers), ``ints``, ``strs``, ``points`` (list of [x, y]) or ``any``. A name ending
in ``?`` is optional. Receivers validate every payload
(``copath.wire.messages.validate_payload``) and count what they reject; bump
``copath.wire.messages.WIRE_VERSION`` (carried by every record) when a field changes meaning.
"""

from __future__ import annotations

from typing import Mapping

__all__ = ["PAYLOADS", "register_payloads"]

PAYLOADS: dict[str, dict[str, str]] = {}
"""Message kind -> schema, as the loaded families registered them."""


def register_payloads(schemas: Mapping[str, Mapping[str, str]]) -> None:
    """Register the schemas of a family's message kinds (again with the same schema: no-op).

    Raises ValueError when a kind is registered with another schema: two families cannot
    give one kind two meanings."""
    for kind, schema in schemas.items():
        schema = dict(schema)
        known = PAYLOADS.get(kind)
        if known is not None and known != schema:
            raise ValueError(f"message kind {kind!r} is registered twice with different schemas: "
                             f"{known} and {schema}")
        PAYLOADS[kind] = schema
