"""The controller side of the OPC UA link: the controller node's plant link.

An ``asyncua`` client on its own thread and event loop, connected to the plant's
server (:mod:`services.io.opcua.server`) with Basic256Sha256 / SignAndEncrypt and
the ``controller`` certificate as both application instance certificate and X.509
identity token. Per sample:

1. a subscription (publishing interval 0: notify at once) reports a data change of
   ``Status/Sample``;
2. one Read request takes the sample's ``Measurements``, ``ProcessTime``,
   ``AppliedMoves``, ``AppliedMoveSeq``, ``Shutdown`` and ``Sample`` (the server
   writes ``Sample`` last, so the read is one whole sample);
3. the controller node processes it as it would a Zenoh measurement (the same
   strict decode, on this thread, as it runs on the Zenoh thread that delivers one);
4. its move goes out in one Write request: the ``Setpoints``, ``AnsweredSample``,
   ``MoveFallback``, ``Tuning`` (the move's tuning set of the plant's loops, empty
   for none), ``ControllerMode`` and the ``ControllerHeartbeat`` counter.

Between moves a heartbeat is written at least every ``heartbeat_s`` wall seconds (a
slow unit's sample is longer than the plant's watchdog). A lost server is the
documented safe action: the link logs it, retries every ``retry_s`` and the plant,
seeing no heartbeat, sheds and holds its valves; the controller node meanwhile gets
no measurement and so moves nothing.

Interface (what :class:`~services.nodes.controller.ControllerNode` calls, shaped like
its Zenoh subscriber and publisher): :meth:`subscribe`, :meth:`put`,
:meth:`undeclare`.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time

from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

from services.io.messages import Measurement, MessageError, MVMessage
from services.io.opcua.certs import application_uri, load_certificates
from services.io.opcua.namespace import node_name, unit_namespace
from services.io.opcua.settings import NAMESPACE_URI, OPCUASettings
from services.io.zenoh_session import PayloadSample

__all__ = ["ControllerOPCUALink", "LinkError", "describe_error"]

log = logging.getLogger("ssmpc.opcua.client")

#: The Status variables read with each sample, in this order, after the Measurements.
SAMPLE_STATUS = ("ProcessTime", "AppliedMoves", "AppliedMoveSeq", "Shutdown", "Incarnation",
                 "Sample")


class LinkError(RuntimeError):
    """The server is not the plant this link expects (a node is missing, a type)."""


def describe_error(exc: BaseException) -> str:
    """One line for an OPC UA failure: the status code's name and what it means here."""
    if isinstance(exc, ua.UaStatusCodeError):
        code = type(exc).__name__
        hint = {"BadUserAccessDenied": "this identity may not do that",
                "BadIdentityTokenRejected": "the server does not take this identity token",
                "BadCertificateUntrusted": "the certificate is not from the link's CA",
                "BadSecurityPolicyRejected": "the server wants Basic256Sha256/SignAndEncrypt",
                "BadNodeIdUnknown": "no such node on the server"}.get(code, "")
        return f"{code}{': ' + hint if hint else ''}"
    if isinstance(exc, ConnectionError | OSError):
        return f"cannot reach the server ({exc.__class__.__name__}: {exc})"
    if isinstance(exc, TimeoutError | asyncio.TimeoutError):
        return "the server did not answer in time"
    return f"{exc.__class__.__name__}: {exc}"


class ControllerOPCUALink:
    """The controller's plant link over OPC UA; see the module docstring.

    Parameters
    ----------
    cfg : UnitConfig
    settings : OPCUASettings
    identity : str
        Certificate to use from ``settings.cert_dir`` (``controller``; ``operator``
        for tests of the roles).
    """

    def __init__(self, cfg, settings: OPCUASettings, *, identity: str = "controller") -> None:
        if not isinstance(settings, OPCUASettings):
            raise TypeError("settings: expected OPCUASettings")
        self.cfg = cfg
        self.unit = cfg.unit
        self.settings = settings
        self.identity = identity
        self.paths = load_certificates(settings.cert_dir)
        measurements, setpoints = unit_namespace(cfg)
        self.meas_names = [v.name for v in measurements]
        self.mv_names = [v.name for v in setpoints]
        self.nu = len(self.mv_names)
        self.connected = threading.Event()
        self.last_error: str | None = None
        self.counters = {"samples": 0, "moves": 0, "heartbeats": 0, "write_errors": 0,
                         "connects": 0}
        self.round_trip_s: list[float] = []  # notification -> move written, s (bench)
        self._callback = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._closing = False
        self._stop: asyncio.Event | None = None
        self._client = None
        self._beat = 0
        #: the controller mode written to ``Status/ControllerMode`` with every heartbeat
        #: and move (``on``, ``warm`` or ``off``; the node sets it)
        self.controller_mode = "on"
        self._last_write = 0.0
        self._last_seq = -1
        self._arrived = 0.0

    # -- the controller node's interface ------------------------------------------------
    def subscribe(self, callback) -> ControllerOPCUALink:
        """Start the link; ``callback(sample)`` gets each new sample (returns self,
        the controller node's "subscriber")."""
        self._callback = callback
        self._thread = threading.Thread(target=self._thread_main, name="ssmpc-opcua-client",
                                        daemon=True)
        self._thread.start()
        return self

    def wait_connected(self, timeout_s: float) -> bool:
        return self.connected.wait(timeout_s)

    def put(self, payload: bytes) -> None:
        """Write a move (an encoded :class:`~services.io.messages.MVMessage`) with a
        heartbeat, from any thread; returns at once (failures are counted and logged)."""
        loop = self._loop
        if loop is None or self._closing or not self.connected.is_set():
            return
        try:
            msg = MVMessage.from_bytes(payload, unit=self.unit, nu=self.nu)
        except MessageError as exc:
            log.error("move not written: %s", exc)
            return
        coro = self._write_move(msg)
        try:
            if threading.get_ident() == self._loop_thread:
                loop.create_task(coro)
            else:
                asyncio.run_coroutine_threadsafe(coro, loop)
        except RuntimeError:  # the loop closed meanwhile
            coro.close()

    def undeclare(self) -> None:
        """Stop the link (idempotent): the session is closed, the thread joined."""
        if self._closing:
            return
        self._closing = True
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(stop.set)
            except RuntimeError:
                pass
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(10.0)

    close = undeclare

    def status(self) -> dict:
        return {"io": "opcua", "endpoint": self.settings.endpoint,
                "connected": self.connected.is_set(), "last_error": self.last_error,
                **self.counters}

    # -- the link's thread ---------------------------------------------------------------
    def _thread_main(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        self._loop_thread = threading.get_ident()
        try:
            loop.run_until_complete(self._main())
        except Exception:
            log.exception("OPC UA link of %s stopped", self.unit)
        finally:
            self.connected.clear()
            _cancel_pending(loop)
            loop.close()

    async def _main(self) -> None:
        self._stop = asyncio.Event()
        if self._closing:
            return
        while not self._stop.is_set():
            try:
                await self._session()
            except Exception as exc:
                text = describe_error(exc)
                if text != self.last_error:
                    log.warning("OPC UA link to %s: %s; retrying every %g s",
                                self.settings.endpoint, text, self.settings.retry_s)
                self.last_error = text
            self.connected.clear()
            self._client = None
            try:
                await asyncio.wait_for(self._stop.wait(), self.settings.retry_s)
            except TimeoutError:
                pass

    async def _connect(self):
        p = self.paths
        client = Client(self.settings.endpoint, timeout=self.settings.timeout_s)
        client.application_uri = application_uri(self.identity)
        client.name = client.description = f"ssmpc {self.identity}"
        client.session_timeout = 600_000  # ms: the server's longest
        await client.set_security(SecurityPolicyBasic256Sha256, str(p.cert(self.identity)),
                                  str(p.key(self.identity)),
                                  server_certificate=str(p.cert("plant")),
                                  mode=ua.MessageSecurityMode.SignAndEncrypt)
        await client.load_client_certificate(str(p.cert(self.identity)))
        await client.load_private_key(p.key(self.identity))
        return client

    async def _session(self) -> None:
        client = await self._connect()
        lost = asyncio.Event()

        async def on_lost(exc) -> None:
            lost.set()

        client.connection_lost_callback = on_lost
        await client.connect()
        try:
            idx = await client.get_namespace_index(NAMESPACE_URI)

            def nid(folder, name=""):
                return ua.NodeId(node_name(self.unit, folder, name), idx)

            self._read_ids = ([nid("Measurements", n) for n in self.meas_names]
                              + [nid("Status", n) for n in SAMPLE_STATUS])
            self._sp_ids = [nid("Setpoints", n) for n in self.mv_names]
            self._move_ids = self._sp_ids + [nid("Status", n) for n in (
                "AnsweredSample", "MoveFallback", "Tuning", "ControllerMode",
                "ControllerHeartbeat")]
            self._beat_ids = [nid("Status", "ControllerMode"), nid("Status", "ControllerHeartbeat")]
            for n, dv in zip(self._read_ids + self._move_ids, await client.uaclient.read_attributes(
                    self._read_ids + self._move_ids, ua.AttributeIds.Value)):
                if dv.StatusCode is not None and not dv.StatusCode.is_good():
                    raise LinkError(f"node {n.to_string()} does not exist on "
                                    f"{self.settings.endpoint} (is it serving unit {self.unit}?)")
            self._client = client
            sub = await client.create_subscription(0, None, queue_maxsize=8)
            await sub.subscribe_data_change(client.get_node(nid("Status", "Sample")))
            self._last_seq = -1
            self.counters["connects"] += 1
            self.last_error = None
            self.connected.set()
            log.info("OPC UA link to %s up", self.settings.endpoint)
            await self._write_beat()
            consumer = asyncio.ensure_future(self._consume(sub))
            try:
                while not (self._stop.is_set() or lost.is_set() or consumer.done()):
                    try:
                        await asyncio.wait_for(self._stop.wait(),
                                               min(0.1, self.settings.heartbeat_s / 4))
                    except TimeoutError:
                        pass
                    if time.monotonic() - self._last_write >= self.settings.heartbeat_s:
                        await self._write_beat()
                if consumer.done() and consumer.exception() is not None:
                    raise consumer.exception()
                if lost.is_set():
                    raise ConnectionError("connection to the server lost")
            finally:
                consumer.cancel()
        finally:
            self.connected.clear()
            self._client = None
            try:
                await asyncio.wait_for(client.disconnect(), 2.0)
            except Exception:
                pass

    async def _consume(self, sub) -> None:
        async for _event in sub:
            self._arrived = time.perf_counter()
            await self._read_sample()

    async def _read_sample(self) -> None:
        client = self._client
        if client is None:
            return
        dvs = await client.uaclient.read_attributes(self._read_ids, ua.AttributeIds.Value)
        values = [None if dv.Value is None else dv.Value.Value for dv in dvs]
        ny = len(self.meas_names)
        t, u, mv_seq, shutdown, incarnation, seq = values[ny:]
        if not isinstance(seq, int) or seq < 0 or seq <= self._last_seq:
            return  # no sample yet, or one already delivered
        self._last_seq = seq
        try:
            payload = Measurement(unit=self.unit, seq=seq, t=float(t), y=tuple(values[:ny]),
                                  u=tuple(u or ()), mv_seq=int(mv_seq),
                                  shutdown=bool(shutdown),
                                  incarnation=str(incarnation or "")).to_bytes()
        except (MessageError, TypeError, ValueError) as exc:
            log.warning("sample %s not usable: %s", seq, exc)
            return
        self.counters["samples"] += 1
        self._callback(PayloadSample(payload))  # the controller's step, on this thread

    async def _write(self, ids, dvs) -> bool:
        client = self._client
        if client is None:
            return False
        try:
            results = await client.uaclient.write_attributes(ids, dvs)
        except Exception as exc:
            self.counters["write_errors"] += 1
            log.warning("write to %s failed: %s", self.settings.endpoint, describe_error(exc))
            return False
        bad = [(i, r) for i, r in zip(ids, results) if not r.is_good()]
        if bad:
            self.counters["write_errors"] += 1
            log.warning("write refused by the plant: %s", ", ".join(
                f"{i.to_string()}: {r.name}" for i, r in bad))
            return False
        self._last_write = time.monotonic()
        return True

    def _beat_values(self):
        self._beat = (self._beat + 1) % 2**32
        return [ua.DataValue(ua.Variant(self.controller_mode, ua.VariantType.String)),
                ua.DataValue(ua.Variant(self._beat, ua.VariantType.UInt32))]

    async def _write_beat(self) -> None:
        if await self._write(self._beat_ids, self._beat_values()):
            self.counters["heartbeats"] += 1

    async def _write_move(self, msg: MVMessage) -> None:
        D = ua.VariantType.Double
        dvs = [ua.DataValue(ua.Variant(float(x), D)) for x in msg.u]
        dvs += [ua.DataValue(ua.Variant(int(msg.meas_seq), ua.VariantType.Int64)),
                ua.DataValue(ua.Variant(bool(msg.fallback), ua.VariantType.Boolean)),
                ua.DataValue(ua.Variant(msg.tuning or "", ua.VariantType.String))]
        dvs += self._beat_values()
        if await self._write(self._move_ids, dvs):
            self.counters["moves"] += 1
            self.counters["heartbeats"] += 1
            if msg.meas_seq == self._last_seq and self._arrived:
                self.round_trip_s.append(time.perf_counter() - self._arrived)
                if len(self.round_trip_s) > 20_000:
                    del self.round_trip_s[:10_000]


def _cancel_pending(loop) -> None:
    """Cancel the tasks asyncua leaves on a stopping loop (session time-outs ...)."""
    tasks = [t for t in asyncio.all_tasks(loop) if not t.done()]
    for t in tasks:
        t.cancel()
    if tasks:
        loop.run_until_complete(asyncio.gather(*tasks, return_exceptions=True))
