"""Optional abilities of an energy term, beside the small contract of ``skelfem.terms.base.Term``.

A term declares an ability by inheriting its class (``class GroundFriction(Term, History, Lagged,
StickAnchors, ...)``); the model, the solver and the analyses find the terms that have one with
``isinstance`` and never call a hook on a term that did not declare it. Each class's defaults
describe a term that has the ability but does nothing with it, so a term overrides only what it
uses. ``Term`` refuses, when a class is defined, a method that belongs to an ability the class does
not declare (it would never be called), and a method named almost like a hook.

=================  ==========================================================  ======================
ability            hooks                                                       who asks
=================  ==========================================================  ======================
``StepBounds``     max_step, admissible, bounds_steps, sweeps_steps            the line search
``StepCorrection`` step_correction (bones turned along their exact rotation)   the line search
``Constraints``    dirichlet, rigid_body                                       the model's matrix
``Follows``        follow, carry_over (an edit on the same mesh, a start state  Model.refresh, Session
                   interpolated from another mesh)
``History``        end_step, rest, take_notes, history, set_history             load and time steps
``Lagged``         update_lag, lags, set_lags, lags_at, lag_step                Newton, sensitivities
``ContactEvents``  contact_event (a contact formed mid-solve: lag now)          Newton
``StickAnchors``   stick_anchors and what moves them                           gradients through time
``FiniteAnchors``  finite_anchors (where --tol grades the mesh)                 accuracy
``Actuator``       actuated (a control of IK, tracking and optimisation)        analysis
``Verdict``        failure, verdict (no equilibrium: a free object unheld)      Newton, load steps
=================  ==========================================================  ======================
"""
from __future__ import annotations

import copy
from typing import Any

import numpy as np


class StepBounds:
    """A term that bounds the line search's steps or refuses states (self-contact, a free object's
    trust region, friction's slip per step)."""

    bounds_steps: bool = False   # whether max_step can return < 1
    sweeps_steps = False   # max_step sweeps the whole trajectory (continuous collision detection): costly
    #                        for long steps, so Model.max_step asks it last, on the step the others allow

    def max_step(self, u0: np.ndarray, p: np.ndarray) -> float:
        """Largest alpha in [0, 1] such that u0 + s p is admissible for s <= alpha."""
        return 1.0

    def admissible(self, u: np.ndarray) -> bool:
        return True


class StepCorrection:
    """A term that corrects the line search's trial states (bones moved along their exact rotation)."""

    def step_correction(self, u0: np.ndarray, p: np.ndarray, alpha: float):
        """Correction added to the trial state u0 + alpha p (owned DOFs), or None."""
        return None


class Constraints:
    """A term that constrains DOFs: Dirichlet conditions, or nodes that follow a few rigid DOFs."""

    def dirichlet(self) -> list:
        """[(DirichletBC, unrolled local DOFs)] this term imposes."""
        return []

    def rigid_body(self):
        """A :class:`skelfem.terms.rigid.RigidBody` whose nodes this term makes move rigidly, or None.

        The model then solves for the body's rigid DOFs instead of its nodes'
        displacements (identity rows in the matrix, a border in the linear solve).
        """
        return None


class Follows:
    """A term that can follow an edit of the design on the same mesh in place (without it, the term is
    built anew), or adjust a start state interpolated from another mesh."""

    def follow(self, ctx: Any, changed: set) -> bool:
        """Become, in place, the term ctx.design would build on this mesh, whose nodes may have moved.

        changed: the design's dotted keys (``pins.base.region``, ``bones.distal.outline``...) that
        differ from the design this term was built for, live parameters aside (the model sets
        those). True if done (node-position caches dropped, compiled UFL energy still valid);
        False if the term must be built anew. The default is False: built anew.
        """
        return False

    def carry_over(self, u: np.ndarray) -> None:
        """Adjust, in place, a start state u (owned DOFs) interpolated from another mesh after an edit."""


class History:
    """A term with a per-step hook and a history (friction's anchors, a cable's slips, inertia's last
    states), which a tried step can take back (Soft IK's trial solves, a failed load step)."""

    history_fields: tuple = ()   # attributes that hold the term's history (friction's anchors, slip states)

    def end_step(self, model) -> None:
        """Called after every accepted load or time step (history: friction, inertia)."""

    def rest(self) -> None:
        """Back to rest: forget every history (a cable's slips through its via points); the model's
        u is being set to 0 for a solve from rest."""

    def take_notes(self) -> list:
        """Warnings for the next result (a history started at a state the solver did not reach with this
        term as it is now: friction switched on at a loaded state), each once; [] if none."""
        return []

    def history(self):
        """A copy of the term's history (what end_step, update_lag and set_factor change), or None."""
        if not self.history_fields:
            return None
        return {k: copy.deepcopy(getattr(self, k)) for k in self.history_fields}

    def set_history(self, history) -> None:
        """Put back a history returned by history(): a step that was tried and refused leaves nothing."""
        for k, v in (history or {}).items():
            setattr(self, k, copy.deepcopy(v))


class Lagged:
    """A term with lagged quantities (friction's normal forces, a cable channel's limits) that Newton
    solves again after refreshing; exact sensitivities differentiate through them."""

    lag_step = 1e-8    # the step of the differences of lags_at, times the model's size (below a ground's
    #                    penetration, where N(u) has a kink)

    def update_lag(self, model) -> bool:
        """Refresh lagged quantities (friction's normal forces) at a converged state; True: solve again."""
        return False

    def lags_follow_the_step(self) -> bool:
        """Whether the lags kept from the last step always change in a new one (a cable's friction limits
        follow its tensions): Newton's first solve of a step then stops loosely, as its re-solves do."""
        return False

    def lags(self):
        """A copy of the lagged quantities that follow the state (friction's normal forces N, an
        edge's tangent), or None: nothing lagged. At a converged state they are their own fixed
        point, lags_at(u) == lags()."""
        return None

    def set_lags(self, lags) -> None:
        """Put back lagged quantities returned by lags() or lags_at()."""

    def lags_at(self, u: np.ndarray):
        """The lagged quantities as update_lag would measure them at state u, on the present branch
        (which nodes stick, slip, broke away; the anchors), without relaxation: what makes the lagged
        Jacobian exact, J v = H v + d/de gradient(u; lags_at(u + e v))."""
        return None


class ContactEvents:
    """A term that takes up contacts forming during a solve (friction anchoring them): Newton ends the
    SNES solve there and starts again from it (Model.contact_event)."""

    def contact_event(self, u: np.ndarray, static: bool = True) -> bool:
        """Whether a contact formed at the iterate u that the term took up now (static: a solve, not a
        step in time)."""
        return False


class StickAnchors:
    """A term whose history's continuous part (friction's stick anchors) the residual uses: gradients
    through time differentiate through it (skelfem.analysis.adjoint)."""

    def stick_anchors(self):
        """The continuous part of the history that the present state's residual uses (friction's
        stick anchors a, a flat float array), or None. A term with a history but no anchors (cable
        friction) makes derivatives through time approximate."""
        return None

    def set_stick_anchors(self, a) -> None:
        """Put back anchors returned by stick_anchors() (or perturbed ones)."""

    def stick_anchor_step(self) -> tuple[float, float]:
        """(a change of an anchor entry, a change of a displacement in mm), both small against the stick
        zone eps: the steps of the central differences through the anchors (every node stays on its
        branch)."""
        return 1.0, 1.0

    def stick_anchors_in_step(self, a_start, u_start):
        """The anchors a converged step uses, from the anchors a_start it began with and the state
        u_start it began from (a contact that formed during the step is anchored where it was at
        u_start); the term holds the converged step's history."""
        return a_start

    def stick_anchors_after(self, u):
        """The anchors the return map (end_step) would give at state u from the present anchors, with
        the lagged quantities at lags_at(u), on the present branch; changes nothing."""
        return self.stick_anchors()


class FiniteAnchors:
    """A term that acts on small disks or balls of material (cables' ends and bends in silicone)."""

    def finite_anchors(self) -> list:
        """[(centre, radius)]: where the term acts on a small disk (2D) or ball (3D) of material, a near
        point force that --tol grades the mesh around (cables' ends and bends in silicone)."""
        return []


class Actuator:
    """A term whose contraction may be a control of Soft IK, tracking and optimisation (Model.actuators)."""

    actuated: bool = False       # this one is (a tendon; a ligament of the same class is not)


class Verdict:
    """A term that can tell that a state is no equilibrium, or that none lies ahead (a free object that
    nothing holds)."""

    def failure(self, model, converged: bool = True) -> str | None:
        """Why the state is no equilibrium (a free object that nothing holds), or None; converged=False:
        the state where Newton gave up."""
        return None

    def verdict(self, model) -> str | None:
        """Why no equilibrium can lie ahead of the present Newton iterate (a free object falling with nothing
        in its way), or None; Newton ends the solve with it at once (the same answer on every rank). Newton
        asks it after every step of the terms that override it."""
        return None


CAPABILITIES = (StepBounds, StepCorrection, Constraints, Follows, History, Lagged, ContactEvents, StickAnchors,
                FiniteAnchors, Actuator, Verdict)
