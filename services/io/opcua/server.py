"""The plant side of the OPC UA link: the server a DCS would run for one unit.

An ``asyncua`` server (OPC 10000-4 services, the address space of
:mod:`services.io.opcua.namespace`) on its own thread and event loop, attached to a
:class:`~services.nodes.plant.PlantNode` as its plant link:

- each published :class:`~services.io.messages.Measurement` updates
  ``Measurements`` (source timestamp: when the sample went out) and ``Status``,
  ``Status/Sample`` last, so a client notified of a new sample reads a whole one;
- a Write from the controller's identity that sets ``Setpoints`` becomes an
  :class:`~services.io.messages.MVMessage` from the plant's expected sender, handed
  to :meth:`PlantNode.submit_mv`: the same validation and the same zero-order hold
  at the sample boundary as a move over Zenoh;
- ``Status/Tuning`` (String) names the tuning set of the plant's own loops the set
  points go with (TE: :data:`controller.units.te.loops.LOOP_TUNING_SETS`; empty: the
  plant's default); it rides in the move, and a name the plant does not know makes
  the plant refuse the move (``mv_rejected["tuning"]``). ``Status/AppliedTuning`` is
  the set in force, written with each sample;
- while shed, ``Setpoints`` track the moves the plant holds (output tracking), so a
  controller that writes only some of them leaves the others where they are;
- the watchdog: no new ``ControllerHeartbeat`` value for ``watchdog_s`` wall seconds →
  ``WatchdogState`` = ``shed``: no move is taken until a heartbeat comes again, so
  the plant holds its valves while its regulatory layer runs on (ABB 800xA link
  time-out, DeltaV's handshake), its loops back on their default tuning set, and
  ``Tuning`` is cleared, so a returning controller names its set again. A returning
  controller takes the held move from ``AppliedMoves`` (the controller node's
  ``_align``), so its return is bumpless.

Security (OPC 10000-2, -4 §5.6): only the Basic256Sha256 / SignAndEncrypt endpoint;
a client's application certificate must be issued by the link's CA
(:mod:`.certs`); the user is the X.509 identity token's certificate: CN
``controller`` may write ``Setpoints`` and the controller's ``Status`` variables
(``Tuning`` among them), ``operator`` reads; the anonymous token (off unless
``allow_anonymous``) reads.
Writes are checked per item: unknown node → ``BadNodeIdUnknown``, a non-Double →
``BadTypeMismatch``, NaN/inf or outside the instrument range → ``BadOutOfRange``
(``Tuning``: a non-String → ``BadTypeMismatch``, longer than 64 characters →
``BadOutOfRange``), a read-only node → ``BadUserAccessDenied``; any Write from
another identity is refused whole with ``BadUserAccessDenied``.
"""

from __future__ import annotations

import asyncio
import datetime
import logging
import math
import threading
import time

from asyncua import Server, ua
from asyncua.common.utils import ServiceError
from asyncua.crypto.permission_rules import USER_TYPES, User, UserRole
from asyncua.server.address_space import AttributeService
from cryptography import x509
from cryptography.hazmat.primitives.serialization import Encoding
from cryptography.x509.oid import NameOID

from services.io.messages import TUNING_NAME_MAX, MessageError, MVMessage
from services.io.opcua.certs import application_uri, ensure_certificates
from services.io.opcua.namespace import (
    CONTROLLER_MODES,
    CONTROLLER_STATUS,
    PLANT_STATUS,
    node_name,
    unit_namespace,
)
from services.io.opcua.settings import NAMESPACE_URI, OPCUASettings

__all__ = ["PlantOPCUAServer"]

log = logging.getLogger("ssmpc.opcua.server")

#: Identities (certificate CN) and what they may do.
WRITER = "controller"
READERS = ("operator",)


def _types():
    return {"Double": (ua.VariantType.Double, ua.ObjectIds.Double, -1),
            "DoubleArray": (ua.VariantType.Double, ua.ObjectIds.Double, 1),
            "Int64": (ua.VariantType.Int64, ua.ObjectIds.Int64, -1),
            "UInt32": (ua.VariantType.UInt32, ua.ObjectIds.UInt32, -1),
            "String": (ua.VariantType.String, ua.ObjectIds.String, -1),
            "Boolean": (ua.VariantType.Boolean, ua.ObjectIds.Boolean, -1)}


_INITIAL = {"Double": 0.0, "DoubleArray": [], "Int64": -1, "UInt32": 0, "String": "",
            "Boolean": False}


class PlantOPCUAServer:
    """The plant's OPC UA server, a plant link of :class:`~services.nodes.plant.PlantNode`.

    Parameters
    ----------
    cfg : UnitConfig
    settings : OPCUASettings

    The server starts when a plant node attaches it (:meth:`attach`), and stops with
    :meth:`close`. ``status()`` is the link's part of the plant's status.
    """

    def __init__(self, cfg, settings: OPCUASettings) -> None:
        if not isinstance(settings, OPCUASettings):
            raise TypeError("settings: expected OPCUASettings")
        self.cfg = cfg
        self.settings = settings
        self.unit = cfg.unit
        self.measurements, self.setpoints = unit_namespace(cfg)
        self.paths = ensure_certificates(settings.cert_dir)
        self.node = None
        self.state = "shed"  # no controller yet: the plant holds its start values
        self.sheds = 0
        self.moves = 0
        self.refused = {"identity": 0, "type": 0, "range": 0}
        self.last_beat: float | None = None  # time.monotonic of the last heartbeat
        self._seq = 0
        self._last_beat_value = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._stopping: asyncio.Event | None = None
        self._error: BaseException | None = None
        self._server = None
        self.idx = None

    # -- plant-link interface --------------------------------------------------------
    def attach(self, node) -> None:
        """Serve ``node``'s plant; blocks until the endpoint serves.

        Raises
        ------
        ValueError
            The endpoint cannot be served (address in use, bad host), or the unit's
            MV vector does not match the plant's.
        """
        if len(self.setpoints) != node.nu:
            raise ValueError(f"setpoints: the unit has {len(self.setpoints)} MVs, the plant "
                             f"{node.nu}")
        self.node = node
        lo, hi = node.runner.u_lower, node.runner.u_upper
        # the instrument range: the plant's actuator limits, within the unit's MV limits
        self._range = [(max(float(lo[i]), v.lo), min(float(hi[i]), v.hi))
                       for i, v in enumerate(self.setpoints)]
        self._thread = threading.Thread(target=self._thread_main, name="ssmpc-opcua-server",
                                        daemon=True)
        self._thread.start()
        self._ready.wait(60.0)
        if self._error is not None:
            raise ValueError(f"endpoint: cannot serve {self.settings.endpoint} "
                             f"({self._error})") from self._error
        if not self._ready.is_set():
            raise ValueError(f"endpoint: {self.settings.endpoint} not serving within 60 s")

    def publish(self, msg) -> None:
        """Put a :class:`~services.io.messages.Measurement` into the address space
        (from the plant's loop thread; returns at once)."""
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        stamp = datetime.datetime.now(datetime.UTC)
        # the loops' tuning set in force, read on the plant's thread with its sample
        tuning = self.node.runner.tuning or ""
        try:
            loop.call_soon_threadsafe(
                lambda: loop.create_task(self._update(msg, stamp, str(tuning))))
        except RuntimeError:  # closing
            pass

    def status(self) -> dict:
        age = None if self.last_beat is None else time.monotonic() - self.last_beat
        return {"io": "opcua", "endpoint": self.settings.endpoint, "watchdog": self.state,
                "watchdog_s": self.settings.watchdog_s, "heartbeat_age_s": age,
                "sheds": self.sheds, "moves": self.moves, "refused": dict(self.refused)}

    def close(self) -> None:
        loop, stopping = self._loop, self._stopping
        if loop is not None and stopping is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(stopping.set)
            except RuntimeError:
                pass
        if self._thread is not None:
            self._thread.join(10.0)

    # -- the server's thread ---------------------------------------------------------
    def _thread_main(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._main())
        except BaseException as exc:  # reported by attach()
            self._error = exc
            if self._ready.is_set():
                log.exception("OPC UA server of %s stopped", self.unit)
        finally:
            self._ready.set()
            _cancel_pending(loop)
            loop.close()

    async def _main(self) -> None:
        self._stopping = asyncio.Event()
        server = Server()
        await server.init()
        server.set_endpoint(self.settings.endpoint)
        server.set_server_name(f"ssmpc {self.unit} plant")
        await server.set_application_uri(application_uri("plant"))
        await server.load_certificate(str(self.paths.cert("plant")))
        await server.load_private_key(str(self.paths.key("plant")))
        server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt],
                                   permission_ruleset=_Roles(self.settings.allow_anonymous))
        server.set_identity_tokens([ua.X509IdentityToken] + (
            [ua.AnonymousIdentityToken] if self.settings.allow_anonymous else []))
        _install_identities(server, self.paths)
        server.iserver.attribute_service = _GuardedWrites(server.iserver.aspace, self)
        self.idx = await server.register_namespace(NAMESPACE_URI)
        await self._build(server)
        self._server = server
        async with server:
            self._ready.set()
            log.info("OPC UA server of %s on %s", self.unit, self.settings.endpoint)
            await self._watchdog_loop()

    def nid(self, folder: str, name: str = ""):
        return ua.NodeId(node_name(self.unit, folder, name), self.idx)

    async def _build(self, server) -> None:
        idx = self.idx
        types = _types()
        items = [_object_item(ua.NodeId(ua.ObjectIds.ObjectsFolder, 0),
                              ua.NodeId(self.unit, idx), ua.QualifiedName(self.unit, idx),
                              f"{self.cfg.description or self.unit}", ua.ObjectIds.BaseObjectType)]
        for folder in ("Measurements", "Setpoints", "Status"):
            items.append(_object_item(ua.NodeId(self.unit, idx), self.nid(folder),
                                      ua.QualifiedName(folder, idx), folder,
                                      ua.ObjectIds.FolderType))
        await _add(server, items)
        items = []
        start = {"Measurements": [float(y) for y in self.node.runner.y()],
                 "Setpoints": [float(u) for u in self.node.runner.u]}
        for folder, variables, writable in (("Measurements", self.measurements, False),
                                            ("Setpoints", self.setpoints, True)):
            for v, x in zip(variables, start[folder]):
                nid = self.nid(folder, v.name)
                items.append(_variable_item(self.nid(folder), nid, ua.QualifiedName(v.name, idx),
                                            v.description, x, types["Double"], writable,
                                            ua.ObjectIds.AnalogItemType))
        for name, kind, description in PLANT_STATUS + CONTROLLER_STATUS:
            writable = (name, kind, description) in CONTROLLER_STATUS
            value = "shed" if name == "WatchdogState" else _INITIAL[kind]
            items.append(_variable_item(self.nid("Status"), self.nid("Status", name),
                                        ua.QualifiedName(name, idx), description, value,
                                        types[kind], writable, ua.ObjectIds.BaseDataVariableType))
        await _add(server, items)
        props = []
        for folder, variables in (("Measurements", self.measurements),
                                  ("Setpoints", self.setpoints)):
            for v in variables:
                parent = self.nid(folder, v.name)
                eu = ua.EUInformation(NamespaceUri="http://www.opcfoundation.org/UA/units/un/cefact",
                                      UnitId=-1, DisplayName=ua.LocalizedText(v.unit),
                                      Description=ua.LocalizedText(v.unit))
                props.append(_property_item(parent, ua.NodeId(f"{parent.Identifier}.EU", idx),
                                            "EngineeringUnits", eu, ua.ObjectIds.EUInformation))
                if math.isfinite(v.lo) and math.isfinite(v.hi):
                    props.append(_property_item(parent,
                                                ua.NodeId(f"{parent.Identifier}.EURange", idx),
                                                "EURange", ua.Range(Low=v.lo, High=v.hi),
                                                ua.ObjectIds.Range))
        await _add(server, props)
        self._setpoint_ids = [self.nid("Setpoints", v.name) for v in self.setpoints]
        self._meas_ids = [self.nid("Measurements", v.name) for v in self.measurements]
        self._checks = {nid: self._setpoint_check(i) for i, nid in enumerate(self._setpoint_ids)}
        self._checks[self.nid("Status", "ControllerMode")] = _mode_check
        self._checks[self.nid("Status", "AnsweredSample")] = _sample_check
        self._tuning_id = self.nid("Status", "Tuning")
        self._checks[self._tuning_id] = self._tuning_check
        self._beat_id = self.nid("Status", "ControllerHeartbeat")
        self._answered_id = self.nid("Status", "AnsweredSample")
        self._fallback_id = self.nid("Status", "MoveFallback")
        self._state_id = self.nid("Status", "WatchdogState")

    def _setpoint_check(self, i: int):
        lo, hi = self._range[i]

        def check(dv) -> int | None:
            v = dv.Value
            if v is None or v.VariantType != ua.VariantType.Double or not isinstance(
                    v.Value, float):
                self.refused["type"] += 1
                return ua.StatusCodes.BadTypeMismatch
            if not (math.isfinite(v.Value) and lo <= v.Value <= hi):
                self.refused["range"] += 1
                return ua.StatusCodes.BadOutOfRange
            return None

        return check

    def _tuning_check(self, dv) -> int | None:
        """``Status/Tuning``: a String of at most :data:`TUNING_NAME_MAX` characters
        (empty: the plant's default; whether the plant knows the set is its check)."""
        v = dv.Value
        if v is None or v.VariantType != ua.VariantType.String or not isinstance(
                v.Value, str | None):
            self.refused["type"] += 1
            return ua.StatusCodes.BadTypeMismatch
        if v.Value is not None and len(v.Value) > TUNING_NAME_MAX:
            self.refused["range"] += 1
            return ua.StatusCodes.BadOutOfRange
        return None

    # -- measurements in -------------------------------------------------------------
    async def _update(self, msg, stamp, tuning: str = "") -> None:
        if self._server is None:
            return
        write = self._server.iserver.aspace.write_attribute_value
        value = ua.AttributeIds.Value

        def dv(v, vt):
            return ua.DataValue(ua.Variant(v, vt), SourceTimestamp=stamp, ServerTimestamp=stamp)

        D = ua.VariantType.Double
        for nid, y in zip(self._meas_ids, msg.y):
            await write(nid, value, dv(float(y), D))
        await write(self.nid("Status", "AppliedMoves"), value, dv([float(u) for u in msg.u], D))
        await write(self.nid("Status", "AppliedMoveSeq"), value,
                    dv(int(msg.mv_seq), ua.VariantType.Int64))
        await write(self.nid("Status", "ProcessTime"), value, dv(float(msg.t), D))
        await write(self.nid("Status", "Shutdown"), value,
                    dv(bool(msg.shutdown), ua.VariantType.Boolean))
        await write(self.nid("Status", "Incarnation"), value,
                    dv(str(msg.incarnation), ua.VariantType.String))
        await write(self.nid("Status", "AppliedTuning"), value,
                    dv(tuning, ua.VariantType.String))
        if self.state != "ok":  # no controller: the set points track the held moves, so
            # that a controller writing only some of them leaves the others where they are
            for nid, u in zip(self._setpoint_ids, msg.u):
                await write(nid, value, dv(float(u), D))
        await write(self.nid("Status", "Sample"), value, dv(int(msg.seq), ua.VariantType.Int64))

    # -- moves out -------------------------------------------------------------------
    def after_write(self, params, results, user) -> None:
        """A controller's Write has been applied item by item: feed the watchdog on a
        heartbeat; turn written set points into the plant's move, with the tuning set
        ``Tuning`` names (empty: none, the plant's default)."""
        good = {wv.NodeId: wv.Value for wv, r in zip(params.NodesToWrite, results)
                if r.is_good() and wv.AttributeId == ua.AttributeIds.Value}
        beat = self._beat_id in good and good[self._beat_id].Value.Value != self._last_beat_value
        if beat:  # a heartbeat is a counter that moves: a stuck writer is no heartbeat
            self._last_beat_value = good[self._beat_id].Value.Value
            self.last_beat = time.monotonic()
            if self.state != "ok":
                log.warning("controller heartbeat of %s back: moves taken again", self.unit)
                self._set_state("ok")
                self.node.resume_tuning()  # its moves select the loops' tuning set again
        if self.state != "ok" or not any(nid in good for nid in self._setpoint_ids):
            return
        node = self.node
        aspace = self._server.iserver.aspace
        u = tuple(float(aspace.read_attribute_value(nid, ua.AttributeIds.Value).Value.Value)
                  for nid in self._setpoint_ids)
        answered = good.get(self._answered_id)
        meas_seq = int(answered.Value.Value) if answered is not None else int(node.k)
        fb = good.get(self._fallback_id)
        fallback = bool(fb.Value.Value) if fb is not None else False
        # the set written with these set points, else the one written before
        written = good.get(self._tuning_id)
        if written is None:
            written = aspace.read_attribute_value(self._tuning_id, ua.AttributeIds.Value)
        tuning = (written.Value.Value if written.Value is not None else None) or None
        self._seq = max(self._seq + 1, time.time_ns() // 1000, node.last_mv_seq + 1)
        try:
            msg = MVMessage(unit=self.unit, seq=self._seq, meas_seq=meas_seq, u=u,
                            sender=node.expected_sender, fallback=fallback, tuning=tuning)
        except MessageError as exc:  # the checks before the write let none through
            self.refused["range"] += 1
            log.warning("controller write on %s not taken as a move: %s", self.unit, exc)
            return
        node.submit_mv(msg.to_bytes())
        self.moves += 1

    def _set_state(self, state: str) -> None:
        self.state = state
        if self._server is not None:
            asyncio.get_running_loop().create_task(self._server.iserver.aspace.write_attribute_value(
                self._state_id, ua.AttributeIds.Value,
                ua.DataValue(ua.Variant(state, ua.VariantType.String))))

    async def _watchdog_loop(self) -> None:
        period = min(0.05, self.settings.watchdog_s / 10)
        while not self._stopping.is_set():
            try:
                await asyncio.wait_for(self._stopping.wait(), period)
            except TimeoutError:
                pass
            beat = self.last_beat
            if (self.state == "ok" and beat is not None
                    and time.monotonic() - beat > self.settings.watchdog_s):
                self.sheds += 1
                log.warning("no controller heartbeat on %s for %.1f s: shed, valves held",
                            self.unit, self.settings.watchdog_s)
                self._set_state("shed")
                await self._shed_tuning()

    async def _shed_tuning(self) -> None:
        """On a shed: the plant's loops back on their default tuning set, ``Tuning``
        cleared (a returning controller names its set again)."""
        await self._server.iserver.aspace.write_attribute_value(
            self._tuning_id, ua.AttributeIds.Value,
            ua.DataValue(ua.Variant("", ua.VariantType.String)))
        try:  # it waits for the plant's lock (an integration step): off this loop
            await asyncio.to_thread(self.node.shed_tuning)
        except Exception:
            log.exception("%s: the loops could not go back to their default tuning",
                          self.unit)


def _mode_check(dv) -> int | None:
    v = dv.Value
    if v is None or v.VariantType != ua.VariantType.String:
        return ua.StatusCodes.BadTypeMismatch
    return None if v.Value in CONTROLLER_MODES else ua.StatusCodes.BadOutOfRange


def _sample_check(dv) -> int | None:
    v = dv.Value
    if v is None or v.VariantType != ua.VariantType.Int64:
        return ua.StatusCodes.BadTypeMismatch
    return None if v.Value >= 0 else ua.StatusCodes.BadOutOfRange


# -- address-space helpers ---------------------------------------------------------
async def _add(server, items) -> None:
    results = await server.iserver.isession.add_nodes(items)
    for item, r in zip(items, results):
        if not r.StatusCode.is_good():
            raise RuntimeError(f"cannot add node {item.RequestedNewNodeId}: {r.StatusCode}")


def _object_item(parent, nid, qname, description, typedef):
    item = ua.AddNodesItem()
    item.RequestedNewNodeId = nid
    item.BrowseName = qname
    item.NodeClass = ua.NodeClass.Object
    item.ParentNodeId = parent
    item.ReferenceTypeId = ua.NodeId(ua.ObjectIds.Organizes)
    item.TypeDefinition = ua.NodeId(typedef)
    attrs = ua.ObjectAttributes()
    attrs.DisplayName = ua.LocalizedText(qname.Name)
    attrs.Description = ua.LocalizedText(description)
    attrs.EventNotifier = 0
    item.NodeAttributes = attrs
    return item


def _variable_item(parent, nid, qname, description, value, kind, writable, typedef):
    vt, dtype, rank = kind
    item = ua.AddNodesItem()
    item.RequestedNewNodeId = nid
    item.BrowseName = qname
    item.NodeClass = ua.NodeClass.Variable
    item.ParentNodeId = parent
    item.ReferenceTypeId = ua.NodeId(ua.ObjectIds.HasComponent)
    item.TypeDefinition = ua.NodeId(typedef)
    attrs = ua.VariableAttributes()
    attrs.DisplayName = ua.LocalizedText(qname.Name)
    attrs.Description = ua.LocalizedText(description)
    attrs.DataType = ua.NodeId(dtype)
    attrs.Value = ua.Variant(value, vt, is_array=rank == 1)
    attrs.ValueRank = rank
    attrs.ArrayDimensions = [0] if rank == 1 else None
    access = ua.AccessLevel.CurrentRead.mask | (ua.AccessLevel.CurrentWrite.mask if writable
                                                 else 0)
    attrs.AccessLevel = access
    attrs.UserAccessLevel = access
    attrs.WriteMask = 0
    attrs.UserWriteMask = 0
    attrs.Historizing = False
    item.NodeAttributes = attrs
    return item


def _property_item(parent, nid, name, value, dtype):
    item = ua.AddNodesItem()
    item.RequestedNewNodeId = nid
    item.BrowseName = ua.QualifiedName(name, 0)
    item.NodeClass = ua.NodeClass.Variable
    item.ParentNodeId = parent
    item.ReferenceTypeId = ua.NodeId(ua.ObjectIds.HasProperty)
    item.TypeDefinition = ua.NodeId(ua.ObjectIds.PropertyType)
    attrs = ua.VariableAttributes()
    attrs.DisplayName = ua.LocalizedText(name)
    attrs.DataType = ua.NodeId(dtype)
    attrs.Value = ua.Variant(value, ua.VariantType.ExtensionObject)
    attrs.ValueRank = -1
    attrs.AccessLevel = ua.AccessLevel.CurrentRead.mask
    attrs.UserAccessLevel = ua.AccessLevel.CurrentRead.mask
    item.NodeAttributes = attrs
    return item


# -- security ----------------------------------------------------------------------
class _Roles:
    """Which OPC UA services each identity may call (asyncua's permission ruleset):
    the controller all a client needs, the operator and the anonymous user (when
    allowed) all but Write, Call and the node-management services."""

    def __init__(self, allow_anonymous: bool) -> None:
        writes = {ua.NodeId(ua.ObjectIds.WriteRequest_Encoding_DefaultBinary),
                  ua.NodeId(ua.ObjectIds.CallRequest_Encoding_DefaultBinary),
                  ua.NodeId(ua.ObjectIds.HistoryUpdateRequest_Encoding_DefaultBinary)}
        self._all = {ua.NodeId(t) for t in USER_TYPES}
        self._read = self._all - writes
        self._anonymous = self._read if allow_anonymous else set()

    def check_validity(self, user, action_type_id, body) -> bool:
        name = getattr(user, "name", None)
        if name == WRITER:
            return action_type_id in self._all
        if name in READERS:
            return action_type_id in self._read
        return action_type_id in self._anonymous


class _Users:
    """The user of a session: the X.509 identity token's certificate, issued by the
    link's CA, named by its CN; a session with another token is anonymous."""

    def __init__(self, ca) -> None:
        self._ca = ca
        self.token_cert: bytes | None = None  # set by the wrapped verify_x509_token

    def get_user(self, iserver, username=None, password=None, certificate=None):
        token, self.token_cert = self.token_cert, None
        if certificate is None or token is None or certificate is not token:
            return User(role=UserRole.Anonymous)  # no X.509 token: at most read-only
        cn = _issued_cn(self._ca, certificate)
        if cn in (WRITER, *READERS):
            return User(role=UserRole.User, name=cn)
        return None  # BadUserAccessDenied


def _issued_cn(ca, der: bytes) -> str | None:
    """The CN of a DER certificate issued by ``ca`` and valid now, else None."""
    try:
        cert = x509.load_der_x509_certificate(der)
        cert.verify_directly_issued_by(ca)
    except Exception:
        return None
    now = datetime.datetime.now(datetime.UTC)
    if not cert.not_valid_before_utc <= now <= cert.not_valid_after_utc:
        return None
    names = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    return str(names[0].value) if names else None


def _install_identities(server, paths) -> None:
    """Client certificates must come from the link's CA; the X.509 token names the user."""
    ca = x509.load_pem_x509_certificate(paths.ca.read_bytes())

    async def validate(cert, app_description) -> None:
        if _issued_cn(ca, cert.public_bytes(Encoding.DER)) is None:
            raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)

    server.set_certificate_validator(validate)
    users = _Users(ca)
    server.iserver.user_manager = users
    verify = server.iserver.verify_x509_token

    def verify_x509_token(isession, token, signature):
        cert = verify(isession, token, signature)
        users.token_cert = cert
        return cert

    server.iserver.verify_x509_token = verify_x509_token


def _guarded_writes_base():
    return AttributeService


class _GuardedWrites(_guarded_writes_base()):
    """asyncua's attribute service with a check per written item (type, range) before
    the write, and the link's :meth:`PlantOPCUAServer.after_write` after it."""

    def __init__(self, aspace, link: PlantOPCUAServer) -> None:
        super().__init__(aspace)
        self._link = link

    async def write(self, params, user=None):
        user = user if user is not None else User(role=UserRole.Admin)
        if user.role == UserRole.Admin:  # the server itself
            return await super().write(params, user)
        if getattr(user, "name", None) != WRITER:  # the ruleset refuses these first
            self._link.refused["identity"] += 1
            return [ua.StatusCode(ua.StatusCodes.BadUserAccessDenied)
                    for _ in params.NodesToWrite]
        results: list = [None] * len(params.NodesToWrite)
        passing = []
        checks = self._link._checks
        for i, wv in enumerate(params.NodesToWrite):
            check = checks.get(wv.NodeId) if wv.AttributeId == ua.AttributeIds.Value else None
            bad = check(wv.Value) if check is not None else None
            if check is None:  # say that a node does not exist (asyncua: access denied)
                found = self._aspace.read_attribute_value(wv.NodeId, ua.AttributeIds.NodeId)
                if found.StatusCode is not None and not found.StatusCode.is_good():
                    bad = ua.StatusCodes.BadNodeIdUnknown
            if bad is not None:
                results[i] = ua.StatusCode(bad)
            else:
                passing.append(i)
        if passing:
            sub = ua.WriteParameters()
            sub.NodesToWrite = [params.NodesToWrite[i] for i in passing]
            for i, r in zip(passing, await super().write(sub, user)):
                results[i] = r
        try:
            self._link.after_write(params, results, user)
        except Exception:
            log.exception("a controller write could not be applied")
        return results


def _cancel_pending(loop) -> None:
    """Cancel the tasks asyncua leaves on a stopping loop (session time-outs ...)."""
    tasks = [t for t in asyncio.all_tasks(loop) if not t.done()]
    for t in tasks:
        t.cancel()
    if tasks:
        loop.run_until_complete(asyncio.gather(*tasks, return_exceptions=True))
