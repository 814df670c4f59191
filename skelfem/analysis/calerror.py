"""The model's own error in a calibration: what the mesh gets wrong, cell by cell, and what the fit does with it.

A fit on a coarse model absorbs the model's discretisation error into the
parameters: the coarse thumb is too stiff in bending, so its silicone comes
out soft and its tendon far too soft, and the 95 % intervals, which only know
the measurement noise, miss the truth while the misfit looks perfect. So
calibration estimates, for every measured cell (row i, column j), the model's
error and its direction

    e_ij ~ |exact - computed|,   c_ij = y_ij(degree p + 1) - y_ij(degree p)   (skelfem.estimate, same mesh)

at the start and at the estimate, reports max_i e_ij / sigma_j per column, and
(``model_error``):

- ``inflate`` (the default): the fit weighs cell (i, j) by 1 / sqrt(sigma_j^2 + e_ij^2)
  (the start's estimate: a cell the model cannot match counts less); then it is
  *corrected*: refitted, from the estimate, to the data less the model's estimated
  error, d_ij - c_ij (a converged fit only), with c estimated again at each new estimate, until the estimate
  moves by less than 1e-2 in the fit's coordinates (at most 5 refits; the fixed
  point is the fit of the degree p + 1 model, at the cost of the degree p one plus
  one richer solve per row and refit). The correction is carried into the
  covariance as what it is, a systematic error, not noise: the estimate's
  effectivity is 0.6-0.9 where the richer degree resolves the field and lower
  at a finite anchor, so the correction may miss as much as (1 - eff) / eff of
  itself, taken as all of it (eff = 0.5). With the weighted Jacobian A (fit's
  coordinates z), G = (A^T A)^+ A^T and the correction's shift s (in z),
  Cov(z) = G diag(sigma^2 / s~^2) G^T + ((1 - eff) / eff)^2 s s^T (s~ the inflated sigmas).
- ``refine``: halve [mesh] size (re-meshing the session) until max e_ij <= sigma_j / 3
  at the start, fit, and again at the estimate if it is not met there (refitting);
  a refinement that would pass ``max_dofs`` is not made (``capped``: the error left
  is inflated). The error left is corrected and carried as above (a third of sigma in
  every one of many rows still shifts a parameter by more than its noise std).
- ``ignore``: estimated and reported only; the intervals know the noise alone
  (``too_coarse`` says when they should not be trusted).

Without a correction (its refit failed) the model error's share of each std
is the linear bound sum_c |G_kc| e_c / s~_c (the largest shift the estimated
errors can cause whatever their signs).
"""
from __future__ import annotations

import dataclasses
import logging
import math
from typing import Any

import numpy as np

from .caldata import DataError

log = logging.getLogger("skelfem")

MODES = ("inflate", "refine", "ignore")
DEFAULT = "inflate"
TARGET = 1.0 / 3.0          # refine until every cell's model error is below this share of its column's sigma
MAX_DOFS = 100_000          # refine: no mesh above this many degrees of freedom
MAX_REFINEMENTS = 4         # refine: at most this many halvings of [mesh] size in all
EFFECTIVITY = 0.5           # the estimate's effectivity taken (0.6-0.9 where the richer degree resolves the
                            # field, lower at a finite anchor: docs/guide/accuracy.md "How honest"): the
                            # correction may miss (1 - EFFECTIVITY) / EFFECTIVITY of itself, here all of it


def check_mode(mode: str) -> str:
    if mode not in MODES:
        raise DataError(f"model_error {mode!r}: one of {', '.join(MODES)}")
    return mode


class ModelError:
    """The model error of one calibration: the estimates, the cell sigmas of the fit, the covariance's share."""

    def __init__(self, data, mode: str = DEFAULT, max_dofs: int = MAX_DOFS):
        self.data, self.mode, self.max_dofs = data, check_mode(mode), int(max_dofs)
        self.start: Any = None       # (rows, columns) e_ij at the start, NaN where not estimated
        self.end: Any = None         # ... at the estimate
        self.change: Any = None      # (rows, columns) the richer degree's signed change at the estimate
        self.shift: Any = None       # (parameters,) how far the correction moved the estimate, in z
        self.corrections = 0         # refits to the corrected data made
        self.uncorrected: Any = None  # the estimate before the correction
        self.refinements: list = []  # [{"size", "dofs", "max_over_sigma"}] of every mesh tried (refine)
        self.capped = False          # refine: the target not met within max_dofs
        self.std = None              # (parameters,) the model error's share of each std (in the fit's units)

    # -- the estimates ------------------------------------------------------------------------
    def estimate(self, rows, theta, states=None) -> tuple[np.ndarray, np.ndarray]:
        """(e_ij, the richer degree's signed change) at theta (rows solved from states, default their load
        paths from rest)."""
        E, S = rows.errors(np.asarray(theta, float), states)
        bad = int(np.sum(np.isnan(E) & np.isfinite(self.data.values)))
        if bad:
            log.warning("calibrate: no model error estimate for %d measured cells (taken as 0)", bad)
        return E, S

    def corrected(self):
        """The data less the model's estimated error at the estimate (what an exact model would have to
        match, as far as the estimate knows): d_ij - (y_ij(p+1) - y_ij(p))."""
        return dataclasses.replace(self.data, values=self.data.values - np.nan_to_num(self.change))

    def worst(self, E) -> float:
        """max over measured cells of e_ij / sigma_j (NaN: not estimated, taken as 0)."""
        ratio = np.where(np.isfinite(self.data.values), np.nan_to_num(E) / self.data.sigma, 0.0)
        return float(ratio.max()) if ratio.size else 0.0

    @property
    def inflated(self) -> bool:
        """Whether the fit weighs by sigma^2 + e^2 (inflate, or refine stopped by the cap)."""
        return self.mode == "inflate" or (self.mode == "refine" and self.capped)

    def sigma(self) -> np.ndarray:
        """(rows, columns) the sigma each cell is weighted with in the fit."""
        s = np.broadcast_to(self.data.sigma, self.data.values.shape).astype(float)
        if self.inflated and self.start is not None:
            s = np.sqrt(s ** 2 + np.nan_to_num(self.start) ** 2)
        return s

    # -- refine -------------------------------------------------------------------------------
    def wants_finer(self, session, E, at: str = "start") -> bool:
        """Whether refine should halve the session's [mesh] size: the model error E above the target and
        the finer mesh within max_dofs (else ``capped``: the error left is inflated)."""
        worst = self.worst(E)
        self.refinements.append({"size": float(session.design.mesh.size), "dofs": int(session.dofs),
                                 "at": at, "max_over_sigma": worst})
        if self.mode != "refine" or worst <= TARGET:
            return False
        halvings = len({m["size"] for m in self.refinements}) - 1
        if halvings >= MAX_REFINEMENTS or session.dofs * 2 ** session.design.dim > self.max_dofs:
            if not self.capped:
                log.warning("calibrate: the model's error is %.3g sigma on %d DOFs; halving [mesh] size again "
                            "would pass %d DOFs: the error left is inflated", worst, session.dofs, self.max_dofs)
            self.capped = True
            return False
        return True

    def halve(self, session) -> None:
        """Re-mesh the session with half its [mesh] size."""
        size = float(session.design.mesh.size)
        log.info("calibrate: model error above %.3g sigma at mesh size %g: refining to %g", TARGET, size, size / 2)
        session.set({"mesh.size": size / 2})

    # -- the covariance -----------------------------------------------------------------------
    def covariance(self, A, inv, s2: float, mask, sigma) -> np.ndarray:
        """Cov(z) of the estimate: noise part and (unless ignored) the model error's (module doc).

        A: the weighted Jacobian of the fitted cells (mask) in z; inv: (A^T A)^+; sigma: the cells'
        sigmas the fit was weighted with (rows, columns). The model error's share: the part of the
        correction the estimate may have missed,
        (1 - EFFECTIVITY) / EFFECTIVITY |shift|; without a correction (its refit
        failed) the linear bound sum_c |G_kc| e_c."""
        if self.mode == "ignore" or self.end is None:
            self.std = np.zeros(A.shape[1])
            return s2 * inv
        G = inv @ A.T
        noise = (np.broadcast_to(self.data.sigma, sigma.shape) / sigma)[mask]
        if self.shift is not None:
            b = (1.0 - EFFECTIVITY) / EFFECTIVITY * np.asarray(self.shift, float)
        else:
            b = np.abs(G) @ (np.nan_to_num(self.end) / sigma)[mask]
        self.std = np.abs(b)
        return s2 * (G * noise ** 2) @ G.T + np.outer(b, b)

    # -- the report ---------------------------------------------------------------------------
    def report(self, dz=None) -> dict:
        """calibration.json's ``model_error`` (dz: d parameter / d z at the estimate, for each parameter's
        model error share of its std)."""
        d = self.data
        cols = {}
        for j, c in enumerate(d.columns):
            measured = np.isfinite(d.values[:, j])
            entry = {}
            for name, E in (("start", self.start), ("estimate", self.end)):
                if E is None:
                    continue
                e = np.nan_to_num(E[measured, j])
                entry[f"max_at_{name}"] = float(e.max()) if e.size else 0.0
                entry[f"max_over_sigma_at_{name}"] = float(e.max() / d.sigma[j]) if e.size else 0.0
            cols[c] = entry
        worst = self.worst(self.end) if self.end is not None else math.nan
        too_coarse = bool(worst > TARGET)
        if self.mode == "ignore":
            how = "estimated only: the intervals hold the measurement noise alone"
        elif self.mode == "refine" and not self.capped:
            how = (f"refined to mesh size {self.refinements[-1]['size']:g} (max e/sigma {worst:.3g}); "
                   "the error left is corrected and carried into the intervals")
        elif self.mode == "refine":
            how = (f"refined to mesh size {self.refinements[-1]['size']:g}, where a finer mesh would pass "
                   f"{self.max_dofs} DOFs; the error left (max e/sigma {worst:.3g}) is inflated, corrected "
                   "and carried into the intervals")
        else:
            how = ("the fit weighs each cell by sigma^2 + e^2, is corrected by the estimated error and "
                   "carries the correction into the intervals")
        if self.mode != "ignore" and self.shift is None:
            how += " (no correction: its refit failed; a linear bound instead)"
        return {"mode": self.mode, "how": how, "target_over_sigma": TARGET, "max_over_sigma": worst,
                "too_coarse": too_coarse, "capped": self.capped, "meshes": self.refinements,
                "columns": cols, "corrections": self.corrections, "effectivity": EFFECTIVITY,
                "not_estimated": (int(np.sum(np.isnan(self.end) & np.isfinite(d.values)))
                                  if self.end is not None else None),
                "uncorrected": ({p.key: float(v) for p, v in zip(d.parameters, self.uncorrected)}
                                if self.uncorrected is not None and self.mode != "ignore" else None),
                "std_share": ({p.key: float(b * abs(g)) for p, b, g in zip(d.parameters, self.std, dz)}
                              if self.std is not None and dz is not None else None)}
