"""``ssmpc bench te-closed-loop``: the TE cascade offline, 0 -> 2 -> 3 over 48 h.

For each strategy (SSMPC, fixed-model MPC, PI baseline) ``--runs`` closed-loop runs
of ``--hours`` process hours (grade 2 requested at 1 h, grade 3 at 25 h) on the
original plant at 1.8 s, supervisory sample 36 s (``controller.units.te.control``):

- "<strategy> process rate": process hours per wall second of the whole loop
  (plant, inner PI loops, supervisory controller, recording);
- "<strategy> controller step": wall time of one supervisory step (for the MPC
  strategies: adaptation, switching and the QP), median / p99 / max over all
  samples of all runs, in ms.

Runs do not stop at an interlock trip (the plant freezes as the original does), so
every run covers the same process time; the first trip, if any, is reported with
the case (``shutdown_h``). Model building and compilation happen before timing.

Measured (AMD EPYC, 2 vCPU shared with other work; ``--runs 2``, the code before and
after the closed loop's glue cuts run alternately, three pairs per set; rate: slowest
and best run of each bench over the set, step: the benches' medians):

======================  ===========  ============  =============  =============
set (load avg)          code         ssmpc ph/s    ssmpc step ms  fixed / pi
                                                   (median)       ph/s (best)
======================  ===========  ============  =============  =============
quiet (1.3-3.1)         before       9.6-14.8      0.32-0.35      24.9 / 87
                        after        11.5-18.1     0.27-0.28      30.8 / 124
2.4-3.5                 before       10.7-13.5     0.36-0.40      23.0 / 77
                        after        8.2-16.1      0.28-0.37      25.5 / 112
3.1-5.1                 before       6.4-14.9      0.32-0.51      21.0 / 81
                        after        8.7-17.1      0.27-0.34      29.4 / 125
4.3-6.7                 before       3.9-12.6      0.36-0.66      16.8 / 58
                        after        6.4-10.6      0.31-0.47      27.9 / 112
======================  ===========  ============  =============  =============

In the quiet set every pair's ssmpc rate rose, by 18-22 % (best runs 13.8 / 14.8 /
9.8 -> 16.7 / 18.1 / 11.6 process-h/s).

On 4 x 2 alternated 48 h runs in one process each (load 4.4-6.8) the CPU time gave
11.5 -> 12.6 process-h/s (median; best 12.7 -> 16.8). Where an ssmpc sample goes
(method timers, share of the sample's wall time, both codes, load 6-9): the core's
step (adaptation, index, switching; the MPC law and its QP 14-16 %) 32-37 %; the core's
bookkeeping after the move (shared state, the covariance step and its floor check
12-15 %, the estimators' preparation, the law's refresh ahead 3 %) 25-28 %; the
steady-state targets 15-16 % before, 12-14 % after; the plan's references 6-7 % ->
5 %; the rest of the TE step 4-5 %; the loop's recording 7-8 % -> 5-6 %; the plant
and its inner PI loops (20 compiled Euler steps) 6-7 %. At 40 process-h/s a sample
has 0.25 ms; the core alone (step and bookkeeping, ~60 % of ~0.55-0.65 ms on a
quiet machine) takes about 0.4 ms, so that rate needs the core's per-sample Python
compiled, not more trimming of the cascade around it.

With the steady-state targets answered at their bounds without a QP and the adaptive
model's steady state computed after the move (``controller.units.te.targets``), two
alternated pairs at load 2.9-3.3 (``--strategies ssmpc --runs 2``): ssmpc 6.7 / 7.1 ->
6.6 / 8.0 process-h/s (within the spread at that load), controller step median 0.77 /
0.79 -> 0.68 / 0.64 ms; the moves bit for bit those before.

With the sample path's small arithmetic compiled (the plan's paths,
:mod:`controller.units.te.path_kernel`; the steady-state targets,
:mod:`controller.units.te.targets_kernel`; the outputs' first-order hold,
:mod:`controller.hold_kernel`; the shared state's update and the index errors' scaling,
:mod:`controller.state_kernel`, :mod:`controller.switching_kernel`) and the glue that
rebuilt the same small objects every sample cut, eight alternated pairs of 48 h runs
in fresh processes, the code before and after (AMD EPYC 2 vCPU, load 3.1-3.6: another
2-process campaign on both cores), moves bit for bit those before:

========  ================  ================  ==================  =================
strategy  process-h/s       process-h/s       step median ms      step p99 ms
          before            after             before -> after     before -> after
========  ================  ================  ==================  =================
ssmpc     12.4 (10.5-14.4)  16.5 (13.6-19.1)  0.44 -> 0.31        0.98 -> 0.75
fixed     17.7 (16.2-21.1)  28.7 (22.0-30.5)  0.38 -> 0.25        0.86 -> 0.49
========  ================  ================  ==================  =================

(medians over the pairs, ranges in brackets; the rate of each pair rose by 1.12-1.75x
for ssmpc, median 1.20, and 1.36-1.88x for fixed, median 1.48). What an ssmpc sample
still spends (py-spy, share of the run's wall time): the normalized least squares'
covariance products and step, BLAS on (213, r <= 80) factors, 13-14 %; the plant and
its inner loops 9 %; the MPC step 14 % (DAQP 4 %, the QP vectors 3 %); the
steady-state targets 8 %, their steady state (an 80 x 80 solve every 10 samples) 3 %;
the adaptive model's QP rebuild 2 %; the rest Python glue spread over some 40
functions, none above 3 %.

With the implicit covariance's products compiled (:mod:`controller.lowrank_kernel`:
``P W'`` before an update, the covariance step's block and the Gram border after it)
and a model's steady state for the targets solved as a (5, 5) system instead of one of
the shared order (:func:`controller.units.te.targets.model_steady_state`), on a quiet
machine (load 0.3-1.1; AMD EPYC 2 vCPU), the products alone: ssmpc 38.2 -> 40.4 /
40.9 process-h/s (``--strategies ssmpc``, two benches; step median 0.13 ms, p99
0.20 ms either way), fixed 60.3. The ssmpc sample's bookkeeping after the move fell
from 36-44 to 26 µs (method timers), the estimator's prepare from 26-31 to 18 µs and
its covariance commit from 12-14 to 7 µs. On a busy host the rate swings by a third
from run to run (fixed 41-56 process-h/s within ten minutes); best of four 48 h runs,
the code before and after alternated four times at such a time: 28.2 / 31.5 / 30.0 /
24.2 against 37.4 / 39.5 / 28.8 / 39.0. The moves are those of before within 4e-9
(``tests/data/te_moves``). With the steady-state solve and the plant side's reactor
temperature cascade as well, best of three runs, three rounds alternated on a busy
host: 39.3 / 38.9 / 34.5 process-h/s, against 40.5 / 38.9 / 35.3 with the products
alone and 33.0 / 33.8 / 36.5 before either.
"""

from __future__ import annotations

import os
import time

NAME = "te-closed-loop"
DESCRIPTION = ("TE cascade offline, 0->2->3 over 48 h: process hours per wall second and "
               "the controller step median/p99/max, per strategy")


def add_arguments(parser) -> None:
    parser.add_argument("--runs", type=int, default=3, help="timed runs per strategy (>= 1)")
    parser.add_argument("--hours", type=float, default=48.0, help="process hours per run")
    parser.add_argument("--strategies", default="ssmpc,fixed,pi",
                        help="comma-separated: ssmpc, fixed, pi")


def run(args) -> list[dict]:
    from controller.units.te.control import STRATEGIES, run_te
    from controller.units.te.grades import Leg, TransitionPlan
    from services.bench._common import latency_case, rate_case
    from services.output import CLIError

    runs = int(args.runs)
    hours = float(args.hours)
    if runs < 1:
        raise CLIError(f"runs: need at least one run, got {runs}")
    if not 1.0 <= hours <= 200.0:
        raise CLIError(f"hours: must be in [1, 200], got {hours}")
    strategies = [s.strip() for s in str(args.strategies).split(",") if s.strip()]
    for s in strategies:
        if s not in STRATEGIES:
            raise CLIError(f"strategies: unknown {s!r}; known: {', '.join(STRATEGIES)}")
    plan = TransitionPlan("mode0", (Leg(1.0, "mode2"), Leg(25.0, "mode3")))
    cases = []
    for strat in strategies:
        run_te(strat, plan, 0.5, stop_on_trip=False)  # build models, compile; not timed
        rates, step_ms, trips = [], [], []
        load = os.getloadavg()[0]
        for _ in range(runs):
            start = time.perf_counter()
            r = run_te(strat, plan, hours, stop_on_trip=False)
            rates.append(hours / (time.perf_counter() - start))
            step_ms.extend(r.solve_ms.tolist())
            trips.append(None if r.shutdown is None else round(r.shutdown.time_h, 3))
        common = {"strategy": strat, "hours": hours, "plant_dt_s": 1.8,
                  "sample_s": r.meta["sample_h"] * 3600, "load_avg_1min": round(load, 2),
                  "shutdown_h": trips}
        cases.append(rate_case(f"{strat} process rate", rates, "process-h/s", **common))
        cases.append(latency_case(f"{strat} controller step", step_ms, "ms", **common))
    return cases
