"""Rerun telemetry of a controller node: columnar batches, documented entity paths, blueprint.

Entity paths (DESIGN.md)::

    <unit>/cv/<name>      measured controlled variables
    <unit>/ref/<name>     their references
    <unit>/mv/<name>      manipulated variables
    <unit>/model/active   index of the active model
    <unit>/model/J/<j>    performance index of model j (eq. 4.6), by model name
    <unit>/timing/solve_ms   controller computation per sample, ms
    <unit>/timing/slack_ms   budget left over per sample, ms (negative = deadline miss)

Timelines ``sample`` (sequence) and ``process_time`` (duration, s). Samples are
buffered and sent every N samples with one ``rr.send_columns`` call per entity
(one ``rr.log`` per scalar costs tens of µs). The sink is an ``.rrd`` file by
default, or a viewer's gRPC address (``rerun+http://host:9876/proxy``).

Sending a batch is Python work that holds the interpreter lock: for TE (~60
entities) about 9 ms. A real-time caller therefore sends a batch in slices on its
own sample thread, in the slack after each move (:meth:`TelemetryLogger.start_flush`,
:meth:`TelemetryLogger.flush_until`), instead of in another thread of the same
process, where it would hold up the next sample for the lock.

The blueprint lays out the panels as the seed's Figs. 7.14–7.16: outputs with
their references, the moves, the active model and the J values, and timing.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

__all__ = ["TelemetryLogger", "entity_paths", "blueprint"]


def _safe(name: str) -> str:
    return "".join(c if (c.isalnum() or c in "_-.") else "_" for c in str(name)) or "_"


def entity_paths(unit: str, cv_names: Sequence[str], mv_names: Sequence[str],
                 model_names: Sequence[str], ref_names: Sequence[str] | None = None
                 ) -> list[str]:
    """All entity paths a unit's recording contains."""
    paths = [f"{unit}/cv/{_safe(n)}" for n in cv_names]
    paths += [f"{unit}/ref/{_safe(n)}" for n in (cv_names if ref_names is None else ref_names)]
    paths += [f"{unit}/mv/{_safe(n)}" for n in mv_names]
    paths += [f"{unit}/model/active"]
    paths += [f"{unit}/model/J/{_safe(n)}" for n in model_names]
    paths += [f"{unit}/timing/solve_ms", f"{unit}/timing/slack_ms"]
    return paths


def blueprint(unit: str, cv_names: Sequence[str], ref_names: Sequence[str] | None = None):
    """Panels like Figs. 7.14–7.16: each tracked CV with its reference, MVs, models, timing.

    With more CVs than references (TE: 41 XMEAS, G in product tracked) the other
    CVs share one extra panel.
    """
    import rerun.blueprint as rrb

    ref_names = list(cv_names if ref_names is None else ref_names)
    cv_views = [
        rrb.TimeSeriesView(name=n, origin=f"/{unit}",
                           contents=[f"/{unit}/cv/{_safe(n)}", f"/{unit}/ref/{_safe(n)}"])
        for n in ref_names
    ]
    if len(ref_names) < len(cv_names):
        cv_views.append(rrb.TimeSeriesView(name="all outputs", origin=f"/{unit}/cv"))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Grid(*cv_views, name="outputs and references"),
            rrb.Vertical(
                rrb.TimeSeriesView(name="moves", origin=f"/{unit}/mv"),
                rrb.TimeSeriesView(name="active model", origin=f"/{unit}/model/active"),
                rrb.TimeSeriesView(name="J", origin=f"/{unit}/model/J"),
                rrb.TimeSeriesView(name="timing (ms)", origin=f"/{unit}/timing"),
            ),
            column_shares=[2, 1],
        ),
        collapse_panels=True,
    )


class TelemetryLogger:
    """Buffer per-sample values and send them to Rerun in columnar batches.

    Parameters
    ----------
    unit : str
    cv_names, mv_names : sequence of str
    sink : str or Path or None
        ``.rrd`` path, or a viewer address starting with ``rerun+http://`` /
        ``rerun://``; None disables telemetry (every call is a no-op).
    batch : int
        Samples per batch.
    recording_id : str, optional
        Rerun recording id; a restarted node passes its previous one, so that its
        files open in the viewer as one recording. Default: a new id.
    ref_names : sequence of str, optional
        CVs that have a reference (default: all ``cv_names``).
    """

    def __init__(self, unit: str, cv_names: Sequence[str], mv_names: Sequence[str],
                 sink: str | Path | None, batch: int = 50, recording_id: str | None = None,
                 ref_names: Sequence[str] | None = None) -> None:
        self.unit = unit
        self.cv_names = tuple(cv_names)
        self.ref_names = self.cv_names if ref_names is None else tuple(ref_names)
        self.mv_names = tuple(mv_names)
        self.batch = int(batch)
        self.model_names: tuple[str, ...] = ()
        self.rec = None
        self.recording_id: str | None = None
        self.samples_logged = 0
        self.clock = time.perf_counter  # the clock flush_until's deadline is on
        self._rows: list[tuple] = []
        self._jobs: list[tuple[list, str, np.ndarray]] = []  # a batch being sent in slices
        self._jobs_rows = 0
        if sink is None:
            return
        import rerun as rr

        self._rr = rr
        import uuid

        self.recording_id = recording_id or f"ssmpc-{unit}-{uuid.uuid4().hex[:12]}"
        self.rec = rr.RecordingStream(f"ssmpc-{unit}", recording_id=self.recording_id)
        sink = str(sink)
        if sink.startswith(("rerun+http://", "rerun://", "rerun+https://")):
            self.rec.connect_grpc(sink)
        else:
            Path(sink).parent.mkdir(parents=True, exist_ok=True)
            self.rec.save(sink)
        self.rec.send_blueprint(blueprint(unit, self.cv_names, self.ref_names))

    @property
    def enabled(self) -> bool:
        return self.rec is not None

    def add(self, sample: int, t: float, y, r, u, active: int, model_names: Sequence[str], J,
            solve_ms: float, slack_ms: float, *, auto_flush: bool = True) -> bool:
        """Buffer one sample; return True when ``batch`` samples are buffered.

        With ``auto_flush`` the batch is sent right away; otherwise the caller
        sends it with :meth:`flush`, or in slices with :meth:`start_flush` and
        :meth:`flush_until`.
        """
        if self.rec is None:
            return False
        if tuple(model_names) != self.model_names:
            if self._rows:
                self.flush()
            self.model_names = tuple(model_names)
        self._rows.append((int(sample), float(t), np.asarray(y, float), np.asarray(r, float),
                           np.asarray(u, float), int(active), np.asarray(J, float),
                           float(solve_ms), float(slack_ms)))
        full = len(self._rows) >= self.batch
        if full and auto_flush:
            self.flush()
        return full

    @property
    def flushing(self) -> bool:
        """True while a batch started by :meth:`start_flush` has entities left to send."""
        return bool(self._jobs)

    def flush(self) -> None:
        """Send everything buffered now: a batch being sent and the samples after it."""
        self.flush_until(float("inf"))
        if self._rows:
            self.start_flush()
            self.flush_until(float("inf"))

    def start_flush(self) -> None:
        """Take the buffered samples as one batch to send (one ``send_columns`` per
        entity) with :meth:`flush_until`; a batch still being sent is finished first.
        Samples added from now on go into the next batch."""
        if self._jobs:
            self.flush_until(float("inf"))
        if self.rec is None or not self._rows:
            return
        rr = self._rr
        rows, self._rows = self._rows, []
        seq = np.array([r[0] for r in rows], dtype=np.int64)
        tp = np.array([r[1] for r in rows], dtype=float)
        idx = [rr.TimeColumn("sample", sequence=seq),
               rr.TimeColumn("process_time", duration=tp)]
        jobs = []

        def add(path: str, values) -> None:
            jobs.append((idx, path, np.asarray(values, float)))

        Y = np.vstack([r[2] for r in rows])
        R = np.vstack([r[3] for r in rows])
        U = np.vstack([r[4] for r in rows])
        for i, n in enumerate(self.cv_names):
            add(f"{self.unit}/cv/{_safe(n)}", Y[:, i])
        for i, n in enumerate(self.ref_names):
            add(f"{self.unit}/ref/{_safe(n)}", R[:, i])
        for i, n in enumerate(self.mv_names):
            add(f"{self.unit}/mv/{_safe(n)}", U[:, i])
        add(f"{self.unit}/model/active", [r[5] for r in rows])
        J = [r[6] for r in rows]
        if self.model_names and all(j.shape == (len(self.model_names),) for j in J):
            Jm = np.vstack(J)
            for i, n in enumerate(self.model_names):
                add(f"{self.unit}/model/J/{_safe(n)}", Jm[:, i])
        add(f"{self.unit}/timing/solve_ms", [r[7] for r in rows])
        add(f"{self.unit}/timing/slack_ms", [r[8] for r in rows])
        jobs.reverse()  # popped from the end, sent in the order above
        self._jobs, self._jobs_rows = jobs, len(rows)

    def flush_until(self, deadline: float) -> bool:
        """Send entities of the batch being sent until :attr:`clock` (default
        ``time.perf_counter``) passes ``deadline``, checked before each entity (one
        entity's ``send_columns`` is ~0.15 ms for a batch of 100 samples). Returns True
        when the batch is out."""
        rr = self._rr if self.rec is not None else None
        while self._jobs:
            if self.clock() > deadline:
                return False
            idx, path, values = self._jobs.pop()
            rr.send_columns(path, indexes=idx, columns=rr.Scalars.columns(scalars=values),
                            recording=self.rec)
            if not self._jobs:
                self.samples_logged += self._jobs_rows
                self._jobs_rows = 0
        return True

    def close(self) -> None:
        """Flush what is buffered and close the sink (the file is complete afterwards)."""
        if self.rec is None:
            return
        self.flush()
        self.rec.flush()
        try:
            self.rec.disconnect()
        except Exception:  # older SDKs: flush is enough
            pass
        self.rec = None
