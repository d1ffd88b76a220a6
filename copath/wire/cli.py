"""Command-line options shared by every copath program that joins a run's network."""

from __future__ import annotations

import argparse

from .session import SessionConfig

__all__ = ["add_config_arguments", "session_config_from_args"]


def add_config_arguments(parser: argparse.ArgumentParser, default_mode: str = "client") -> None:
    """Add ``--connect/-e``, ``--listen/-l``, ``--mode``, ``--zenoh-config`` and ``--cfg KEY:VALUE``."""
    g = parser.add_argument_group("zenoh")
    g.add_argument("-e", "--connect", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
    g.add_argument("-l", "--listen", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable)")
    g.add_argument("--mode", choices=("client", "peer", "router"), default=default_mode,
                   help=f"zenoh session mode (default {default_mode})")
    g.add_argument("--zenoh-config", metavar="FILE", help="a Zenoh JSON5 config file to start from")
    g.add_argument("--cfg", action="append", default=[], metavar="KEY:VALUE",
                   help="a Zenoh config entry as KEY:JSON5_VALUE (repeatable); multicast scouting stays off")


def session_config_from_args(args: argparse.Namespace) -> SessionConfig:
    extra = []
    for item in args.cfg:
        key, sep, value = item.partition(":")
        if not sep or not key:
            raise ValueError(f"--cfg {item!r} is not allowed; expected KEY:VALUE, e.g. transport/link/tx/lease:1000")
        if key.startswith("scouting/multicast"):
            raise ValueError(f"--cfg {item!r} is not allowed; multicast scouting stays off for run isolation")
        extra.append((key, value))
    return SessionConfig(mode=args.mode, connect=tuple(args.connect), listen=tuple(args.listen),
                         extra=tuple(extra), config_file=args.zenoh_config)
