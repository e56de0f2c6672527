"""``ssmpc sim te``: open-loop Tennessee Eastman run to CSV, as the original driver runs it.

The CSV has the layout of the reference files (``time`` in h, ``XMEAS1..41``,
``XMV1..12``, ``X1..X50``; full double precision): a row every
``--record-every`` hours from t = 0 (rounded to whole Euler steps) through
``--hours``, and a final row at the evaluation where an interlock trips (the
run stops there). Everything is validated before the run; the file is written
atomically.
"""

from __future__ import annotations

import io
import math
import time

from plant_sim.base import PlantInputError
from plant_sim.tennessee_eastman.random import ORIGINAL_SEED
from plant_sim.tennessee_eastman.simulator import ROW_COLUMNS, SimSettings, TESimulator
from services.output import CLIError, atomic_output, check_writable, emit_json

__all__ = ["run", "parse_idv", "rows_to_csv"]

MAX_ROWS = 2_000_000


def parse_idv(text: str) -> tuple[int, float]:
    """Parse ``K@T_H`` (or ``K``, meaning from t = 0) into (IDV number, switch-on time in h)."""
    k_s, _, t_s = str(text).partition("@")
    try:
        k = int(k_s.strip())
    except ValueError as exc:
        raise CLIError(f"idv: expected K@T_H with K in 1..20, got {text!r}") from exc
    if not 1 <= k <= 20:
        raise CLIError(f"idv: unknown disturbance IDV({k}) in {text!r}; known: 1..20")
    t = 0.0
    if t_s.strip():
        try:
            t = float(t_s)
        except ValueError as exc:
            raise CLIError(f"idv: switch time {t_s!r} of IDV({k}) is not a number") from exc
        if not math.isfinite(t) or t < 0:
            raise CLIError(f"idv: switch time of IDV({k}) must be finite and >= 0, got {t_s!r}")
    return k, t


def rows_to_csv(rows) -> str:
    """CSV text with the reference header; values as shortest exact decimal (round trip)."""
    buf = io.StringIO()
    buf.write(",".join(ROW_COLUMNS) + "\n")
    for row in rows:
        buf.write(",".join(repr(float(v)) for v in row) + "\n")
    return buf.getvalue()


def _reject_unit_options(args) -> None:
    for name, used in (("op", getattr(args, "op", None)),
                       ("step", getattr(args, "step", [])),
                       ("plot", getattr(args, "plot", None)),
                       ("sample", getattr(args, "sample", None))):
        if used:
            raise CLIError(f"{name}: option --{name} does not apply to plant te "
                           f"(use --idv, --record-every)")


def run(args) -> int:
    """Entry point called by :mod:`services.cli.sim` for plant ``te``."""
    _reject_unit_options(args)
    hours = args.hours
    if hours is None or not math.isfinite(hours) or hours <= 0:
        raise CLIError(f"hours: duration must be a positive finite number, got {hours!r}")
    try:
        settings = SimSettings(dt_s=args.dt, noise=(args.noise == "on"),
                               seed=ORIGINAL_SEED if args.seed is None else args.seed,
                               literals=args.literals, mode=args.mode)
    except PlantInputError as exc:
        raise CLIError(str(exc)) from exc
    dt_h = settings.dt_h
    n_steps = int(round(hours / dt_h))
    if n_steps < 1:
        raise CLIError(f"hours: {hours} is shorter than one step of {settings.dt_s} s")
    rec_h = args.record_every
    if rec_h is None or not math.isfinite(rec_h) or rec_h <= 0:
        raise CLIError(f"record-every: must be a positive number of hours, got {rec_h!r}")
    rec_steps = int(round(rec_h / dt_h))
    if rec_steps < 1:
        raise CLIError(f"record-every: {rec_h} h is shorter than one step of {settings.dt_s} s")
    if n_steps // rec_steps + 2 > MAX_ROWS:
        raise CLIError(f"record-every: {rec_h} h gives more than {MAX_ROWS} rows over {hours} h")
    idvs = [parse_idv(s) for s in args.idv]
    for k, t in idvs:
        if t >= hours:
            raise CLIError(f"idv: IDV({k}) switches on at {t} h, after the run ends ({hours} h)")
    check_writable(args.out, "out")

    t_load = time.perf_counter()
    # load the compiled code (numba cache) on a throwaway plant, so the speed is the run's
    TESimulator(settings).run_steps(1, record_every=1, stop_on_trip=True)
    load_s = time.perf_counter() - t_load
    sim = TESimulator(settings)
    for k, t in idvs:
        sim.set_idv(k, True, at_h=t)
    start = time.perf_counter()
    # one more evaluation than steps: the row at t = hours comes from the evaluation there
    rows = sim.run_steps(n_steps + 1, record_every=rec_steps, stop_on_trip=True)
    wall = time.perf_counter() - start
    sd = sim.shutdown
    sim_hours = sd.time_h if sd is not None else n_steps * dt_h
    text = rows_to_csv(rows)
    with atomic_output(args.out, "w", field="out") as fh:
        fh.write(text)
    summary = {
        "plant": "te",
        "out": str(args.out),
        "rows": int(rows.shape[0]),
        "hours": hours,
        "dt_s": settings.dt_s,
        "steps": n_steps,
        "record_every_h": rec_steps * dt_h,
        "noise": settings.noise,
        "seed": settings.seed,
        "mode": settings.mode,
        "literals": settings.literals,
        "idv": [{"idv": k, "on_h": t} for k, t in idvs],
        "shutdown": None if sd is None else sd.as_dict(),
        "final_time_h": float(rows[-1, 0]) if rows.shape[0] else 0.0,
        "cost_usd_per_h": sim.cost(),
        "speed": {"sim_hours_per_wall_s": sim_hours / wall if wall > 0 else None,
                  "wall_s": wall, "load_s": load_s},
    }
    msg = f"wrote {rows.shape[0]} rows to {args.out}"
    if sd is not None:
        msg += f"; shutdown at {sd.time_h:.4f} h ({sd.reason})"
    print(msg)
    if args.json:
        emit_json(summary)
    return 0
