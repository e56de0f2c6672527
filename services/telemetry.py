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

The blueprint lays out the panels as the seed's Figs. 7.14–7.16: outputs with
their references, the moves, the active model and the J values, and timing.
"""

from __future__ import annotations

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
        self._rows: list[tuple] = []
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
        sends it with :meth:`flush` (e.g. from a worker thread, off the sample loop).
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

    def flush(self) -> None:
        """Send the buffered samples (one ``send_columns`` per entity)."""
        if self.rec is None or not self._rows:
            return
        rr = self._rr
        rows, self._rows = self._rows, []  # one swap: add() may run in another thread
        seq = np.array([r[0] for r in rows], dtype=np.int64)
        tp = np.array([r[1] for r in rows], dtype=float)
        idx = [rr.TimeColumn("sample", sequence=seq),
               rr.TimeColumn("process_time", duration=tp)]

        def send(path: str, values) -> None:
            rr.send_columns(path, indexes=idx,
                            columns=rr.Scalars.columns(scalars=np.asarray(values, float)),
                            recording=self.rec)

        Y = np.vstack([r[2] for r in rows])
        R = np.vstack([r[3] for r in rows])
        U = np.vstack([r[4] for r in rows])
        for i, n in enumerate(self.cv_names):
            send(f"{self.unit}/cv/{_safe(n)}", Y[:, i])
        for i, n in enumerate(self.ref_names):
            send(f"{self.unit}/ref/{_safe(n)}", R[:, i])
        for i, n in enumerate(self.mv_names):
            send(f"{self.unit}/mv/{_safe(n)}", U[:, i])
        send(f"{self.unit}/model/active", [r[5] for r in rows])
        J = [r[6] for r in rows]
        if self.model_names and all(j.shape == (len(self.model_names),) for j in J):
            Jm = np.vstack(J)
            for i, n in enumerate(self.model_names):
                send(f"{self.unit}/model/J/{_safe(n)}", Jm[:, i])
        send(f"{self.unit}/timing/solve_ms", [r[7] for r in rows])
        send(f"{self.unit}/timing/slack_ms", [r[8] for r in rows])
        self.samples_logged += len(rows)

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
