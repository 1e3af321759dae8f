"""Exercise 3: the base action (paper Sec. 4, last part: Eqs. (18)-(19), (22)-(23) and the FSM).

The base planner samples end states (t_e, l_e, v_e) and joins the ego's present state to each by a
quintic l(t) along its path (Eq. (18)), fixed by six boundary conditions (Eq. (19)). Each candidate
gets a cost (Eq. (20)); a finite state machine picks one: drive, slow down to stop, or brake in
emergency. The acceleration of the chosen trajectory at the next step, capped by IDM, is the base
action a_base (Eqs. (22)-(23)).

Fill in the three TODO(student) blocks (numpy), then:    python -m exercises.check 3
Read docs/PAPER.md, note 3 (why Eq. (22) keeps a sign). Don't read planner.py's quintic_coefficients,
state_machine and base_acceleration before you are done: they are the answer.
"""
import numpy as np


def quintic_coefficients(l0, v0, a0, le, ve, ae, te):
    """The coefficients (c1, ..., c6) of Eq. (18), l(t) = c1 t^5 + c2 t^4 + c3 t^3 + c4 t^2 + c5 t + c6,
    that meet the six boundary conditions of Eq. (19):

        l(0) = l0,   l'(0) = v0,   l''(0) = a0,   l(te) = le,   l'(te) = ve,   l''(te) = ae.

    l0, le [m], v0, ve [m/s], a0, ae [m/s^2], te [s] > 0: numbers or arrays that broadcast. Returns an
    array of shape broadcast(inputs) + (6,): c1 (the t^5 coefficient) first, c6 (the constant) last.
    Closed form or a linear solve (np.linalg.solve broadcasts over stacked 6 x 6 systems): your choice.
    """
    # TODO(student): Eq. (19)
    raise NotImplementedError("Eq. (19)")


def state_machine(cost, drive_ids, stop_ids, K1):
    """The FSM on the candidates' costs of Eq. (20) -> (mode, index).

    cost (C,): each candidate's cost, np.inf if it is kinematically infeasible; drive_ids, stop_ids:
    slices of cost, the "drive" candidates and the "slow down to stop" ones (v_e = 0); K1: the
    collision weight of Eq. (20). K1 exceeds the sum of all the other terms, so a candidate is
    collision-free exactly when its cost < K1.

    Drive along the cheapest drive candidate if it is collision-free: ("drive", its index in cost);
    else stop along the cheapest stop candidate if that one is: ("stop", its index in cost); else
    ("brake", None), the emergency brake.
    """
    # TODO(student): the state machine
    raise NotImplementedError("the FSM")


def base_acceleration(l_dd_t1, a_idm, cfg):
    """Eqs. (22)-(23): a_base [m/s^2] from the chosen candidate's l''(t1) (t1 = one step ahead) [m/s^2]
    and IDM's acceleration a_IDM toward the leader [m/s^2] (np.inf: nobody ahead).

    Eq. (22): a_t1 = sqrt(l''(t1)^2 + d''(t1)^2), with d'' = 0 on the ego's fixed path; Eq. (23):
    a_base = min(a_t1, a_IDM), then kept within the ego's limits [cfg.a_min, cfg.a_max]. Returns a float.
    """
    # TODO(student): Eqs. (22)-(23)
    raise NotImplementedError("Eqs. (22)-(23)")
