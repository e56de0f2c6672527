"""The Δu MPC as a control law of the state-shared multiple-model controller.

:class:`MPCLaw` implements :class:`controller.multimodel.ControlLaw`: at each sample
the multiple-model controller has adapted and switched; the law reads the shared
state ``n(k)`` and the active model's prediction form ``(Φ_j, Γ_j, C_j)``
(:meth:`controller.state_shared.StateSharedModel.prediction_form`) and runs one
deadline-safe :class:`~controller.mpc.controller.MPCController` step on it. Because
the formulation uses ``Δn = n(k) − n(k−1)`` and the measured output, a switch needs no
state reset; each model's condensed QP is cached under its index and rebuilt only
when an adaptive model's Θ has moved enough to matter, between samples.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from controller.interfaces import QP_WORK_KEYS
from controller.mpc.controller import ModelView, MPCController
from controller.mpc.settings import MPCSettings
from controller.packing import pack_array, unpack_array

__all__ = ["MPCLaw", "SharedStateSource", "relative_change"]

_NO_J = np.zeros(0)  # a view's J: the law does not report the index (read only)
_NO_J.setflags(write=False)


class SharedStateSource:
    """:class:`~controller.mpc.controller.StateSource` reading a ``StateSharedModel``.

    The multiple-model controller advances the shared state itself; this source only
    remembers the previous state for Δn and reports the model the caller selected.

    An adaptive model's Θ changes every sample; rebuilding its exact prediction form
    (a matrix exponential of the shared order) and its QP every sample would cost tens
    of milliseconds at TE size. For an adaptive model this source therefore uses the
    shared state's own discrete recursion (no matrix exponential)::

        n(k+1) = [[Fd, 0], [Gd Θ1ᵀ, Fd + Gd Θ2ᵀ]] n(k) + [Gd; 0] u(k),   y = Θᵀ n + b

    which is exactly how the controller advances n with y held over the sample, and
    refreshes it (and the model's QP) only when Θ has moved since the form was made by
    more than ``refresh_tol`` relative to it, ``‖Θ − Θ_made‖_F > refresh_tol ‖Θ_made‖_F``,
    and at most every ``min_refresh_samples`` samples (a model that adapts fast, such as
    the random n = 40 model of ``ssmpc bench mpc-step --synthetic-te``, moves by more than
    the tolerance at every sample; its QP build then costs ~16 ms).
    The test runs between samples (:meth:`refresh_ahead`, from
    :meth:`MPCLaw.finish_sample`, after the move is out), so no sample's critical path
    pays for a rebuild; a law used without ``finish_sample`` applies the same test when
    the sample observes. Fixed models use the exact ZOH prediction form.

    **Measured threshold** (48 h TE run 0 → 2 → 3 of the ``ssmpc`` strategy, 4801
    samples of 36 s, ``OPENBLAS_NUM_THREADS=1``): max |Δu| over all 12 XMVs (% of
    valve range) against moves with the form rebuilt whenever Θ changed at all
    (``refresh_tol = 0``, 4801 rebuilds)::

        refresh rule                                 rebuilds   max |Δu| (%)
        every 10 samples (before)                       481       0.020
        refresh_tol = 1e-5, at most every 10 samples    269       0.018
        refresh_tol = 1e-4                              165       0.012
        refresh_tol = 1e-4, at most every 5 samples     155       0.012
        refresh_tol = 1e-4, at most every 10 samples    129       0.017
        refresh_tol = 1e-3                               16       0.048
        refresh_tol = 1e-2 ... 1e-1                       3       0.048

    The defaults (``1e-4``, at most every 10 samples) keep the moves within 0.02 % of
    valve range of the always-current model (the documented tolerance; the periodic
    rule it replaces was 0.020 % off) with about a quarter of the rebuilds, and never
    rebuild more often than the periodic rule did. Above ``1e-3`` only the
    re-initializations (jumps of Θ) rebuild.
    """

    #: Default relative change of Θ that makes an adaptive model's form stale.
    REFRESH_TOL = 1e-4
    #: Default least number of samples between two refreshes of one model.
    MIN_REFRESH_SAMPLES = 10

    def __init__(self, refresh_tol: float = REFRESH_TOL,
                 min_refresh_samples: int = MIN_REFRESH_SAMPLES) -> None:
        if isinstance(refresh_tol, bool) or not isinstance(refresh_tol, int | float) or not (
                math.isfinite(refresh_tol) and refresh_tol >= 0):
            raise ValueError(f"refresh_tol: must be a finite number >= 0, got "
                             f"{refresh_tol!r}")
        if isinstance(min_refresh_samples, bool) or not isinstance(
                min_refresh_samples, int) or min_refresh_samples < 1:
            raise ValueError(f"min_refresh_samples: must be an integer >= 1, got "
                             f"{min_refresh_samples!r}")
        self.refresh_tol = float(refresh_tol)
        self.min_refresh_samples = int(min_refresh_samples)
        self.ssm = None
        self.model = 0
        self.n_prev: np.ndarray | None = None
        self._snap: dict[int, tuple] = {}
        self._made: dict[int, int] = {}
        self._decided: dict[int, int] = {}  # sample whose form refresh_ahead chose
        self._restored: dict[int, np.ndarray] = {}  # Θ of restored snapshots, (2nm, p)
        self._k = 0
        self.refreshes = 0
        self._names_of: tuple | None = None  # (ssm, its k, its names as a tuple)

    def _discrete_form(self, j: int, theta=None):
        ssm = self.ssm
        nm = ssm.Fd.shape[0]
        th = np.asarray(ssm.theta(j) if theta is None else theta, dtype=float)
        Phi = np.zeros((2 * nm, 2 * nm))
        Phi[:nm, :nm] = ssm.Fd
        Phi[nm:, :nm] = ssm.Gd @ th[:nm].T
        Phi[nm:, nm:] = ssm.Fd + ssm.Gd @ th[nm:].T
        Gamma = np.zeros((2 * nm, ssm.m))
        Gamma[:nm] = ssm.Gd
        return Phi, Gamma, th.T.copy()

    def _form(self, j: int):
        if self.ssm.kind(j) != "adaptive":
            return self.ssm.prediction_form(j)
        if self._decided.get(j) == self._k or not self._stale(j, self._k):
            self._restore_form(j)
            return self._snap[j]
        return self._refresh(j, self._k)

    def _restore_form(self, j: int) -> None:
        """The form of a restored snapshot, made from its Θ on first use."""
        if j not in self._snap and j in self._restored:
            self._snap[j] = self._discrete_form(j, self._restored[j])

    def _stale(self, j: int, k: int) -> bool:
        """Adaptive model j has no form yet, or, ``min_refresh_samples`` or more since
        its form was made (at sample ``k``), its Θ has moved by more than
        ``refresh_tol`` (relative, Frobenius)."""
        if j not in self._made:
            return True
        if k - self._made[j] < self.min_refresh_samples:
            return False
        made = self._snap[j][2] if j in self._snap else self._restored[j].T  # Θ_madeᵀ
        now = self.ssm.theta_rows(j)
        return relative_change(now, made) > self.refresh_tol

    def _refresh(self, j: int, k: int):
        self._snap[j] = self._discrete_form(j)
        self._restored.pop(j, None)
        self._made[j] = k
        self.refreshes += 1
        return self._snap[j]

    def refresh_ahead(self, j: int):
        """Decide adaptive model ``j``'s form for the next :meth:`observe` now: refresh
        it when its Θ has moved by more than ``refresh_tol``; returns the new form or
        None (unchanged, or not adaptive).

        Run between samples (after the move is out), it takes the refresh and the QP
        build that follows it off the next sample's critical path: that sample uses the
        form decided here, whatever its own adaptation does to Θ.
        """
        if self.ssm is None or self.ssm.kind(j) != "adaptive":
            return None
        nxt = self._k + 1
        self._decided[j] = nxt
        return self._refresh(j, nxt) if self._stale(j, nxt) else None

    def observe(self, u_prev, y) -> ModelView:
        n = self.ssm.n
        n_prev = n if self.n_prev is None else self.n_prev
        self.n_prev = n
        self._k += 1
        pf = self._form(self.model)
        return ModelView(self.model, n, n_prev, pf[0], pf[1], pf[2], self.model, _NO_J,
                         self._names())

    def _names(self) -> tuple[str, ...]:
        """The models' names, kept while the model set is the same (names change only
        when a model is added)."""
        ssm, cached = self.ssm, self._names_of
        if cached is None or cached[0] is not ssm or cached[1] != ssm.k:
            cached = self._names_of = (ssm, ssm.k, tuple(ssm.names))
        return cached[2]

    def checkpoint(self) -> dict[str, Any]:
        """Δn memory and the adaptive forms: the sample counter and, per adaptive
        model, the sample and Θ of its form and the sample :meth:`refresh_ahead`
        decided it for (so a restored source predicts with the very form the original
        would use)."""
        snaps = {}
        for j, made in self._made.items():
            th = self._snap[j][2].T if j in self._snap else self._restored[j]  # Θ (2nm, p)
            snaps[str(j)] = {"made": made, "theta": pack_array(th)}
            if j in self._decided:
                snaps[str(j)]["decided"] = self._decided[j]
        return {"n_prev": None if self.n_prev is None else pack_array(self.n_prev),
                "k": self._k, "snapshots": snaps}

    def restore(self, state: dict[str, Any]) -> None:
        n = state.get("n_prev")
        self.n_prev = None if n is None else unpack_array(n)  # packed, or a list
        self._snap.clear()
        self._made.clear()
        self._decided.clear()
        self._restored.clear()
        if "k" not in state:  # an older checkpoint: refresh every adaptive form now
            return
        self._k = int(state["k"])
        for key, snap in (state.get("snapshots") or {}).items():
            j = int(key)
            th = unpack_array(snap["theta"])
            if th.ndim != 2 or not np.isfinite(th).all():
                raise ValueError(f"state.snapshots.{key}.theta: expected a finite matrix")
            self._restored[j] = th  # Θ, shape (2nm, p); the form is built on first use
            self._made[j] = int(snap["made"])
            if "decided" in snap:
                self._decided[j] = int(snap["decided"])

    def restored_forms(self):
        """``(j, form)`` of every adaptive model restored from a checkpoint (the forms
        made now from their Θ), for building their QPs before the first sample."""
        if self.ssm is None:
            return []
        out = []
        for j in list(self._restored):
            if 0 <= j < self.ssm.k and self.ssm.kinds[j] == "adaptive":
                self._restore_form(j)
                out.append((j, self._snap[j]))
        return out


class MPCLaw:
    """Δu MPC control law for :class:`controller.multimodel.MultiModelController`.

    Parameters
    ----------
    settings : MPCSettings
        ``nu = ny = m`` of the state-shared model.
    refresh_tol : float
        Relative change of an adaptive model's Θ that makes its prediction form and
        QP stale (:class:`SharedStateSource`; the forms are part of :meth:`checkpoint`,
        so a restored law makes the same moves).
    min_refresh_samples : int
        Least number of samples between two refreshes of one adaptive model.
    setup_ahead : bool
        A QP rebuilt between samples (:meth:`finish_sample`) also sets its solver's
        workspace up there (DAQP: the factorisation of ``H``), so the next sample only
        solves. Its first solve then takes DAQP's update path, whose round-off differs
        from the set-up path's (QP solutions within
        :data:`controller.mpc.qp.SETUP_AHEAD_ATOL`; measured on the two-phase closed
        loop in ``tests/test_mpc_law.py``). False: the workspace is set up in that
        sample's solve, as before.

    Notes
    -----
    ``compute`` reports the soft output constraint's slack as ``info["slack"]``
    (only when a solve was applied) and the MPC status as ``info["status"]``; a
    time-varying input target is set with :meth:`set_input_target` before each
    sample.
    """

    def __init__(self, settings: MPCSettings,
                 refresh_tol: float = SharedStateSource.REFRESH_TOL,
                 min_refresh_samples: int = SharedStateSource.MIN_REFRESH_SAMPLES,
                 setup_ahead: bool = True) -> None:
        if not isinstance(setup_ahead, bool):
            raise ValueError(f"setup_ahead: expected True or False, got {setup_ahead!r}")
        self.settings = settings
        self.setup_ahead = setup_ahead
        self.source = SharedStateSource(refresh_tol, min_refresh_samples)
        self.mpc = MPCController(settings, self.source, u0=np.zeros(settings.nu))

    def prepare(self, ssm) -> None:
        """Build every model's QP ahead of time (a switch then costs no build)."""
        self.source.ssm = ssm
        for j in range(ssm.k):
            pf = self.source._form(j)
            self.mpc.prepare(j, pf[0], pf[1], pf[2])

    def set_input_target(self, u_target) -> None:
        """Input targets (resting values) from this sample on, shape (nu,).

        See :meth:`controller.mpc.controller.MPCController.set_input_target`; raises
        ``ValueError`` for a wrong length or a non-finite value.
        """
        self.mpc.set_input_target(u_target)

    def set_operator_limits(self, **limits) -> None:
        """An operator's held inputs and limits from this sample on
        (:meth:`controller.mpc.controller.MPCController.set_operator_limits`)."""
        self.mpc.set_operator_limits(**limits)

    def retune(self, settings: MPCSettings, ssm) -> None:
        """New weights or limits (same sizes and horizons): every model's QP rebuilt now
        (TE: ~3 ms for four models), the law's dynamic state kept."""
        self.mpc.retune(settings)
        self.settings = settings
        self.prepare(ssm)

    @property
    def input_target(self) -> np.ndarray:
        """The input targets in force, shape (nu,) (a copy)."""
        return self.mpc.u_target.copy()

    def reset(self, u, y) -> None:
        self.mpc.u = np.asarray(u, dtype=float).copy()
        self.mpc.filter.reset()
        self.mpc.plan = None
        self.source.n_prev = None

    def finish_sample(self, ssm, model: int) -> None:
        """Between samples: refresh every adaptive model's form and build its QP when
        its Θ has moved by more than ``refresh_tol`` (see
        :meth:`SharedStateSource.refresh_ahead`), the inactive ones too, so that a
        switch to an adaptive model finds its QP ready. ``model`` (the active one) is
        not needed for that; it is part of the law protocol. With ``setup_ahead`` the
        rebuilt QP's solver workspace is set up here too."""
        self.source.ssm = ssm
        for j in range(ssm.k):
            form = self.source.refresh_ahead(j)
            if form is not None:
                self.mpc.prepare(j, form[0], form[1], form[2],
                                 setup_solver=self.setup_ahead)

    def compute(self, k: int, model: int, ssm, y, reference, u_last):
        self.source.ssm = ssm
        self.source.model = int(model)
        self.mpc.u = np.asarray(u_last, dtype=float).copy()
        dec = self.mpc.step(k, 0.0, y, reference)
        info = {"status": dec.status, "fallback": dec.fallback, "alarms": list(dec.alarms),
                "solve_ms": dec.solve_ms}
        if "slack" in dec.extra:
            info["slack"] = dec.extra["slack"]
        info.update((key, dec.extra[key]) for key in QP_WORK_KEYS if key in dec.extra)
        return dec.u, info

    def counters(self) -> dict[str, int]:
        return {f"mpc_{k}": v for k, v in self.mpc.counters.items()}

    def checkpoint(self) -> dict[str, Any]:
        return self.mpc.checkpoint()

    def restore(self, state: dict[str, Any]) -> None:
        """Restore, and build the restored adaptive models' QPs now (not in a sample)."""
        self.mpc.restore(state)
        for j, form in self.source.restored_forms():
            self.mpc.prepare(j, form[0], form[1], form[2])


def relative_change(now: np.ndarray, made: np.ndarray) -> float:
    """``‖now − made‖_F / ‖made‖_F`` (inf when ``made`` is zero and ``now`` is not)."""
    scale = math.sqrt(float(np.vdot(made, made)))
    d = now - made
    diff = math.sqrt(float(np.vdot(d, d)))
    if scale == 0.0:
        return 0.0 if diff == 0.0 else math.inf
    return diff / scale
