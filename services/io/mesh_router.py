"""The authenticated Zenoh router of a mesh: user/password per identity, ACL by role.

``ssmpc up`` runs one in its own process (:func:`open_router`) on a loopback port,
with the credentials of :mod:`services.io.mesh_auth` and the access-control list of
:mod:`services.io.acl`; its nodes join it as Zenoh clients (:func:`node_arguments`)
and listen on nothing themselves, so the router is the only way onto that mesh.
``ssmpc router --credentials DIR`` runs the same router for a mesh across hosts.

Cost, ``ssmpc bench loop --unit U --cases latency,mesh`` (lock-step loop,
measurement out to move back, loopback, the 2-core machine at load average 8-12;
p50 µs, pairs side by side):

=====  =====================================  ==================================
unit   latency: plant and controller peers    mesh: clients of this router (ACL)
=====  =====================================  ==================================
cstr   779, 989, 1067                         1060, 1451, 914
te     1950                                   2479
=====  =====================================  ==================================

Limits: user/password authenticates each node to the router, not the router to the
nodes, and TCP links are not encrypted (``docs/security.md``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from services.io import mesh_auth
from services.io.acl import access_control

__all__ = ["RouterMesh", "router_settings", "open_router", "node_arguments"]


def router_settings(credentials_dir, *, listen=(), connect=(), lease_ms=None,
                    config_file=None):
    """:class:`~services.io.zenoh_session.SessionSettings` of an authenticated router."""
    from services.io.zenoh_session import SessionSettings

    dictionary = mesh_auth.router_dictionary(credentials_dir)
    return SessionSettings(config_file=config_file, mode="router", listen=tuple(listen),
                           connect=tuple(connect), lease_ms=lease_ms,
                           dictionary_file=str(dictionary), access_control=access_control())


@dataclass
class RouterMesh:
    """A running router: its session, endpoint and credentials directory."""

    session: object
    endpoint: str
    credentials_dir: Path
    made: list = field(default_factory=list)

    def close(self) -> None:
        self.session.close()


def open_router(state_dir, *, lease_ms=None) -> RouterMesh:
    """Make (first start) or reuse the credentials in ``<state_dir>/mesh`` and open the
    router on a free loopback port.

    Raises
    ------
    ValueError
        Credentials that cannot be made or are not owner-only, or a router Zenoh
        cannot open.
    """
    from services.io.zenoh_session import free_tcp_endpoint, open_session

    cred_dir = mesh_auth.credentials_directory(state_dir)
    made = mesh_auth.make_credentials(cred_dir)
    endpoint = free_tcp_endpoint()
    session = open_session(router_settings(cred_dir, listen=(endpoint,), lease_ms=lease_ms))
    return RouterMesh(session=session, endpoint=endpoint, credentials_dir=cred_dir, made=made)


def node_arguments(mesh: RouterMesh) -> list[str]:
    """Command-line arguments of a node that joins ``mesh`` as a client with its role's
    credentials (the role is the node's own command)."""
    return ["--mode", "client", "--connect", mesh.endpoint,
            "--credentials", str(mesh.credentials_dir)]
