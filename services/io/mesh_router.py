"""The authenticated Zenoh router of a mesh: user/password per identity, ACL by role.

``ssmpc up`` runs one as a child process of its own (``ssmpc router``, the arguments
of :func:`router_arguments`) on a loopback port it picks once (:func:`plan_mesh`), with
the credentials of :mod:`services.io.mesh_auth` and the access-control list of
:mod:`services.io.acl`; its nodes join it as Zenoh clients (:func:`node_arguments`)
and listen on nothing themselves, so the router is the only way onto that mesh.
A router that dies is restarted by ``up`` on the same endpoint, and the clients'
sessions reconnect by themselves (Zenoh redeclares their subscribers, queryables and
liveliness tokens). ``ssmpc router --credentials DIR`` runs the same router for a mesh
across hosts; :func:`open_router` opens one in the calling process (``ssmpc bench``).

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

__all__ = ["MeshPlan", "RouterMesh", "router_settings", "plan_mesh", "open_router",
           "router_arguments", "node_arguments"]


def router_settings(credentials_dir, *, listen=(), connect=(), lease_ms=None,
                    config_file=None):
    """:class:`~services.io.zenoh_session.SessionSettings` of an authenticated router."""
    from services.io.zenoh_session import SessionSettings

    dictionary = mesh_auth.router_dictionary(credentials_dir)
    return SessionSettings(config_file=config_file, mode="router", listen=tuple(listen),
                           connect=tuple(connect), lease_ms=lease_ms,
                           dictionary_file=str(dictionary), access_control=access_control())


@dataclass(frozen=True)
class MeshPlan:
    """Where a mesh's router listens and its credentials lie, before it runs.

    Attributes
    ----------
    endpoint : str
        The router's loopback endpoint, ``tcp/127.0.0.1:<port>``; a restarted router
        listens on the same one.
    credentials_dir : pathlib.Path
        The owner-only credentials directory (``<state-dir>/mesh``).
    made : list of str
        The identities whose credentials this plan made (empty when reused).
    """

    endpoint: str
    credentials_dir: Path
    made: list = field(default_factory=list)


def plan_mesh(state_dir) -> MeshPlan:
    """Make (first start) or reuse the credentials in ``<state_dir>/mesh`` and pick a
    free loopback port for the router.

    Raises
    ------
    ValueError
        Credentials that cannot be made or are not owner-only.
    """
    from services.io.zenoh_session import free_tcp_endpoint

    cred_dir = mesh_auth.credentials_directory(state_dir)
    made = mesh_auth.make_credentials(cred_dir)
    return MeshPlan(endpoint=free_tcp_endpoint(), credentials_dir=cred_dir, made=made)


def router_arguments(plan: MeshPlan, *, lease_ms=None) -> list[str]:
    """``ssmpc`` arguments of the router process of ``plan``."""
    argv = ["router", "--credentials", str(plan.credentials_dir), "--listen", plan.endpoint]
    return argv + ([] if lease_ms is None else ["--lease-ms", str(int(lease_ms))])


@dataclass
class RouterMesh:
    """A router running in this process: its plan (endpoint, credentials) and session."""

    plan: MeshPlan
    session: object

    def close(self) -> None:
        self.session.close()


def open_router(state_dir, *, lease_ms=None) -> RouterMesh:
    """Make (first start) or reuse the credentials in ``<state_dir>/mesh`` and open the
    router in this process on a free loopback port.

    Raises
    ------
    ValueError
        Credentials that cannot be made or are not owner-only, or a router Zenoh
        cannot open.
    """
    from services.io.zenoh_session import open_session

    plan = plan_mesh(state_dir)
    session = open_session(router_settings(plan.credentials_dir, listen=(plan.endpoint,),
                                           lease_ms=lease_ms))
    return RouterMesh(plan=plan, session=session)


def node_arguments(mesh: MeshPlan) -> list[str]:
    """Command-line arguments of a node that joins ``mesh`` as a client with its role's
    credentials (the role is the node's own command)."""
    return ["--mode", "client", "--connect", mesh.endpoint,
            "--credentials", str(mesh.credentials_dir)]
