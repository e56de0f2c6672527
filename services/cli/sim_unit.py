"""``ssmpc sim`` for the unit plants (cstr, bioreactor, two_phase_reactor, calcium).

Everything is validated before the simulation starts; the CSV (and the optional
PNG) are produced in memory and written atomically, so an error leaves no file.
"""

from __future__ import annotations

import io
import math
import re
from dataclasses import dataclass

import numpy as np

from plant_sim.base import PlantModel
from plant_sim.integrate import PiecewiseConstant, SimulationResult, simulate
from services.cli.plant_info import build_plant, parse_options
from services.output import CLIError, atomic_output, check_writable, emit_json

__all__ = ["run", "parse_step", "StepSpec", "write_csv_text", "plot_result"]

DEFAULT_SAMPLES = 500
_STEP_RE = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*=\s*([^@]+?)\s*@\s*(.+?)\s*$")


@dataclass(frozen=True)
class StepSpec:
    """A step ``name := value`` at time ``t`` on an input or a disturbance."""

    name: str
    kind: str  # "input" or "disturbance"
    index: int
    value: float
    t: float


def _number(text: str, field: str) -> float:
    try:
        v = float(text)
    except ValueError as exc:
        raise CLIError(f"{field}: {text!r} is not a number") from exc
    if not math.isfinite(v):
        raise CLIError(f"{field}: {text!r} is not a finite number")
    return v


def parse_step(text: str, plant: PlantModel, duration: float) -> StepSpec:
    """Parse ``INPUT=VALUE@T`` against ``plant``'s inputs and disturbances."""
    m = _STEP_RE.match(text)
    if not m:
        raise CLIError(f"step: expected INPUT=VALUE@T, got {text!r}")
    name, value_s, t_s = m.groups()
    inputs, dists = plant.names("input"), plant.names("disturbance")
    if name in inputs:
        kind, idx, var = "input", inputs.index(name), plant.input_vars[inputs.index(name)]
    elif name in dists:
        kind, idx, var = ("disturbance", dists.index(name),
                          plant.disturbance_vars[dists.index(name)])
    else:
        raise CLIError(f"step: unknown input {name!r} for plant {plant.name!r}; "
                       f"inputs: {', '.join(inputs)}"
                       + (f"; disturbances: {', '.join(dists)}" if dists else ""))
    value = _number(value_s, f"step {name} value")
    t = _number(t_s, f"step {name} time")
    if not var.lower <= value <= var.upper:
        raise CLIError(f"step {name} value: {value} outside the bounds "
                       f"[{var.lower}, {var.upper}] {var.unit}")
    if t < 0 or t >= duration:
        raise CLIError(f"step {name} time: {t} must lie in [0, {duration}) "
                       f"({plant.time_unit})")
    return StepSpec(name, kind, idx, value, t)


def _schedule(base: np.ndarray, steps: list[StepSpec], kind: str) -> PiecewiseConstant:
    times = sorted({0.0} | {s.t for s in steps if s.kind == kind})
    rows = []
    current = base.astype(float).copy()
    for t in times:
        for s in steps:
            if s.kind == kind and s.t == t:
                current[s.index] = s.value
        rows.append(current.copy())
    return PiecewiseConstant(np.array(times), np.vstack(rows).reshape(len(times), -1))


def write_csv_text(res: SimulationResult) -> str:
    """CSV text: a header of column names, one row per sample, full precision."""
    cols = res.columns()
    buf = io.StringIO()
    buf.write(",".join(c[0] for c in cols) + "\n")
    data = np.column_stack([c[2] for c in cols])
    for row in data:
        buf.write(",".join(repr(float(v)) for v in row) + "\n")
    return buf.getvalue()


def plot_result(res: SimulationResult, title: str) -> bytes:
    """PNG of outputs and inputs against time (matplotlib, Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = ([(n, u, res.y[:, i], "default")
               for i, (n, u) in enumerate(zip(res.output_names, res.output_units))]
              + [(n, u, res.u[:, i], "steps-post")
                 for i, (n, u) in enumerate(zip(res.input_names, res.input_units))])
    fig, axes = plt.subplots(len(panels), 1, sharex=True,
                             figsize=(7, 1.6 * len(panels) + 0.8), squeeze=False)
    for ax, (name, unit, data, style) in zip(axes[:, 0], panels):
        ax.plot(res.t, data, drawstyle=style)
        ax.set_ylabel(f"{name} [{unit}]")
        ax.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel(f"time [{res.time_unit}]")
    axes[0, 0].set_title(title)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()


def _reject_te_options(args) -> None:
    te_only = {"idv": bool(getattr(args, "idv", [])),
               "noise": getattr(args, "noise", "off") != "off",
               "seed": getattr(args, "seed", None) is not None,
               "mode": getattr(args, "mode", "base") != "base"}
    used = [k for k, v in te_only.items() if v]
    if used:
        raise CLIError(f"{used[0]}: option --{used[0]} applies only to plant te")


def run(args) -> int:
    """Entry point called by :mod:`services.cli.sim` for the unit plants."""
    # plant options (e.g. gamma=inf, sigma=ref94, inputs=flows) if the parser offers them
    plant = build_plant(args.plant, parse_options(getattr(args, "option", None)))
    _reject_te_options(args)
    op = plant.operating_point(args.op or "OPI")
    duration = args.hours
    if duration is None or not math.isfinite(duration) or duration <= 0:
        raise CLIError(f"hours: duration must be a positive finite number, got {duration!r}")
    sample = args.sample if args.sample is not None else duration / DEFAULT_SAMPLES
    if not math.isfinite(sample) or sample <= 0:
        raise CLIError(f"sample: must be a positive finite number, got {args.sample!r}")
    if sample > duration:
        raise CLIError(f"sample: {sample} is longer than the duration {duration}")
    if duration / sample > 1e6:
        raise CLIError(f"sample: {sample} gives more than 1e6 rows over {duration}")
    steps = [parse_step(s, plant, duration) for s in args.step]
    check_writable(args.out, "out")
    if args.plot:
        check_writable(args.plot, "plot")
        if _same_path(args.plot, args.out):
            raise CLIError("plot: must differ from --out")

    u_sched = _schedule(op.u, steps, "input")
    d_sched = _schedule(op.d, steps, "disturbance") if plant.nd else None
    try:
        res = simulate(plant, op.x, u_sched, t_end=duration, dt=sample, d=d_sched)
    except RuntimeError as exc:
        raise CLIError(f"simulation failed: {exc}", code=1) from exc
    csv_text = write_csv_text(res)
    png = None
    if args.plot:
        png = plot_result(res, f"{plant.name} from {op.name}")
    with atomic_output(args.out, "w", field="out") as fh:
        fh.write(csv_text)
    if png is not None:
        with atomic_output(args.plot, "wb", field="plot") as fh:
            fh.write(png)
    summary = {
        "plant": plant.name, "op": op.name, "duration": duration,
        "time_unit": plant.time_unit, "sample": sample, "rows": int(res.t.size),
        "out": str(args.out), "plot": args.plot,
        "columns": [{"name": n, "unit": u} for n, u, _ in res.columns()],
        "steps": [{"name": s.name, "value": s.value, "t": s.t} for s in steps],
        "final": {"y": dict(zip(res.output_names, res.y[-1].tolist())),
                  "x": dict(zip(res.state_names, res.x[-1].tolist()))},
        "reconstructed": bool(plant.reconstructed),
    }
    print(f"wrote {res.t.size} rows to {args.out}" + (f" and {args.plot}" if args.plot else ""))
    if args.json:
        emit_json(summary)
    return 0


def _same_path(a: str, b: str) -> bool:
    from pathlib import Path

    return Path(a).resolve() == Path(b).resolve()
