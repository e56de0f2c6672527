"""``ssmpc router``: a Zenoh router from the Python library.

For meshes across hosts when the ``zenohd`` binary is not installed: opens a
session in router mode (``--listen`` endpoints, or a ``--zenoh-config`` file)
and serves until SIGINT/SIGTERM or ``--duration``. With ``--credentials DIR``
(made by ``ssmpc credentials``) it accepts only sessions that authenticate with
the dictionary of ``DIR`` and filters them with ssmpc's access-control list by
identity (:mod:`services.io.mesh_router`, :mod:`services.io.acl`), replacing any
``access_control`` of the config file.
"""

from __future__ import annotations

__all__ = ["register", "run_router"]


def register(sub) -> None:
    p = sub.add_parser("router", help="run a Zenoh router (Python library) for a multi-host mesh")
    p.add_argument("--zenoh-config", metavar="FILE", help="Zenoh JSON5 config for the router")
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on (default tcp/0.0.0.0:7447)")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="other routers to connect to")
    p.add_argument("--lease-ms", type=int, default=None, help="transport lease, ms")
    p.add_argument("--credentials", metavar="DIR", default=None,
                   help="mesh credentials (ssmpc credentials): authenticate every session "
                        "and apply the access-control list by identity")
    p.add_argument("--duration", type=float, default=None, help="stop after this many wall s")
    p.set_defaults(func=run_router)


def run_router(args) -> int:
    from services.io.zenoh_session import SessionSettings, open_session
    from services.nodes.run import _ready, _stop_event

    listen = tuple(args.listen) or (() if args.zenoh_config else ("tcp/0.0.0.0:7447",))
    if args.credentials is not None:
        from services.io.mesh_router import router_settings

        settings = router_settings(args.credentials, listen=listen, connect=args.connect,
                                   lease_ms=args.lease_ms, config_file=args.zenoh_config)
    else:
        settings = SessionSettings(config_file=args.zenoh_config, mode="router",
                                   listen=listen, connect=tuple(args.connect),
                                   lease_ms=args.lease_ms)
    stop = _stop_event(args.duration)
    session = open_session(settings)
    try:
        _ready("router", "-", zid=session.zid(), listen=",".join(listen),
               auth="usrpwd+acl" if args.credentials else "none")
        stop.wait()
    finally:
        session.close()
    return 0
