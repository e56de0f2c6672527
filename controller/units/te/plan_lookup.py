"""The TE grade plan's references of one supervisory sample in one evaluation.

Each sample the TE controller (:mod:`controller.units.te.control`) reads three
first-order paths of its :class:`~controller.units.te.grades.TransitionPlan` (seed
§7.7: references between grades as first-order responses): the XMEAS references at
the sample and over the MPC's horizon (``xmeas_ref``), the valve references at the
sample and at the horizon's end (``xmv_ref``) and the D-share feedforward at the
sample (``d_fraction_ref``). The three switch at the same times (the plan's legs), so
one table of all 41 + 12 + 1 columns, each with its own time constant, gives them in
one evaluation of the plan's own arithmetic, ``target + (start - target) *
exp(-dt / tau)`` in the segment of the last switch (``grades._relax``), element for
element: the values are bit for bit those of the three calls.

Measured (plan 0 -> 2 -> 3, horizon 10, one sample's lookup, best of 3 x 20,000
calls; 2 cores at a load average of 9-10):

=========================  ==========
three plan calls           96-118 us
one evaluation (here)      42-62 us
=========================  ==========

The arithmetic on each side of the exponential is compiled
(:mod:`controller.units.te.path_kernel`: 14-25 -> 6.6-7.1 us a sample, the same
values).
"""

from __future__ import annotations

import numpy as np

from controller.units.te.path_kernel import compile_path_kernels, path_exponents, path_values

__all__ = ["SampleReferences"]


class SampleReferences:
    """The plan's references at ``t`` and ``horizon`` samples ahead, for one plan.

    Parameters
    ----------
    plan : TransitionPlan
        The plan (its switch tables; plans of other types are not handled here).
    sample_h : float
        Supervisory sample, h.
    horizon : int
        Samples ahead (>= 0): rows ``t + sample_h * k`` for ``k = 0 .. horizon``.
    """

    #: columns of the table: XMEAS 1-41, XMV 1-12, the D share
    N_XMEAS, N_XMV = 41, 12

    def __init__(self, plan, sample_h: float, horizon: int) -> None:
        tables = plan._tables
        xm, xv, df = tables["xmeas"], tables["xmv"], tables["d_fraction"]
        if not (np.array_equal(xm.times, xv.times) and np.array_equal(xm.times, df.times)):
            raise ValueError("plan: its reference tables switch at different times")
        self.plan = plan
        self.horizon = int(horizon)
        self._times = np.ascontiguousarray(xm.times, dtype=float)
        self._start = np.ascontiguousarray(np.hstack((xm.start, xv.start, df.start)), float)
        self._target = np.ascontiguousarray(np.hstack((xm.target, xv.target, df.target)),
                                            float)
        # a table's time constant: one for every segment and column (0-d), or one per
        # segment and column ((L, n): a valve closing more slowly than it opens)
        n_seg = self._times.size
        self._tau = np.hstack([np.broadcast_to(np.asarray(t.tau, dtype=float),
                                               (n_seg, t.start.shape[1]))
                               for t in (xm, xv, df)])  # (L, 54)
        self._positive = self._tau > 0
        self._all_positive = bool(self._positive.all())
        self._tau_div = np.ascontiguousarray(np.where(self._positive, self._tau, 1.0))
        self._offsets = float(sample_h) * np.arange(self.horizon + 1)
        self._seg = np.empty(self.horizon + 1, dtype=np.int64)
        self._x = np.empty((self.horizon + 1, self._tau_div.shape[1]))
        compile_path_kernels()

    @classmethod
    def for_plan(cls, plan, sample_h: float, horizon: int) -> SampleReferences | None:
        """A lookup for ``plan``, or None when it is not a plan with switch tables (a
        held plan of the service answers the three calls itself)."""
        tables = getattr(plan, "_tables", None)
        if not isinstance(tables, dict) or not {"xmeas", "xmv", "d_fraction"} <= set(tables):
            return None
        return cls(plan, sample_h, horizon)

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray, float]:
        """References of the sample at ``t`` (h).

        Returns
        -------
        ym_all : ndarray (horizon + 1, 41)
            XMEAS references at ``t + sample_h * k``.
        xv_all : ndarray (2, 12)
            Valve references at ``t`` and at ``t + horizon * sample_h``.
        d_share : float
            D share of the D+E feed at ``t``.
        """
        seg, x = self._seg, self._x  # scratch: the answers are new arrays
        path_exponents(float(t), self._offsets, self._times, self._tau_div, seg, x)
        np.exp(x, out=x)  # numpy's exp, as the plan's own evaluation (path_kernel)
        return path_values(x, seg, self._positive, self._all_positive, self._start,
                           self._target, self.N_XMEAS, self.N_XMV)
