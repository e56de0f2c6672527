"""``ssmpc credentials``: make, check or rotate the Zenoh mesh credentials.

One password per identity (plant, controller, api, cli) and the router's dictionary
in ``<state-dir>/mesh`` (:mod:`services.io.mesh_auth`), owner-only. ``ssmpc up`` makes
them by itself on its first start; this command is for a mesh across hosts (copy
``<role>.key`` to the host of that node, ``passwords`` to the router's) and for
rotation (``--rotate``: new passwords for all; restart the router and the nodes).
"""

from __future__ import annotations

__all__ = ["register", "run_credentials"]


def register(sub) -> None:
    p = sub.add_parser("credentials", help="make, check or rotate the Zenoh mesh credentials")
    p.add_argument("--state-dir", default=".",
                   help="state directory; the credentials go to <state-dir>/mesh (default .)")
    p.add_argument("--rotate", action="store_true",
                   help="draw new passwords for every identity (restart router and nodes)")
    p.add_argument("--json", action="store_true", help="print the JSON document")
    p.set_defaults(func=run_credentials)


def run_credentials(args) -> int:
    from services.io import mesh_auth
    from services.output import emit_json

    directory = mesh_auth.credentials_directory(args.state_dir)
    made = mesh_auth.make_credentials(directory, rotate=args.rotate)
    for role in mesh_auth.ROLES:  # read back: every file owner-only and well formed
        mesh_auth.node_credentials(directory, role)
    mesh_auth.router_dictionary(directory)
    doc = {"directory": str(directory), "made": made,
           "users": {r: mesh_auth.user_name(r) for r in mesh_auth.ROLES},
           "router_dictionary": str(directory / mesh_auth.DICTIONARY_FILE)}
    if not args.json:
        what = ("rotated" if args.rotate else "made") if made else "checked (reused)"
        print(f"mesh credentials {what} in {directory} (owner-only): "
              + ", ".join(f"{r} as {u}" for r, u in doc["users"].items()))
    emit_json(doc)
    return 0
