"""Exercise 1: the timing factor beta and the blend (paper Sec. 4, Eqs. (6)-(8), (11)-(12)).

The timing taker picks T in 1..T_max: "execute the actor's action a_t over the next T steps". Within
those T steps the share beta of a_t rises from near 0 to 1 (Eq. (6)); the rest of the executed action
is the planner's base action (Eq. (7)). In the real environment only the first step counts: beta(T)
:= beta(T, 1) (Eq. (11)), the timing factor, blends a_t with a_base (Eq. (12)). The imagination scores
a decision with the discounted sum of its T step rewards (Eq. (8)).

Fill in the three TODO(student) blocks (numpy), then:    python -m exercises.check 1
Don't read tarl.py's beta, blend and discounted_sum before you are done: they are the answer.
"""
import numpy as np


def beta(T, dt=1, *, omega):
    """Eq. (6): the share of the actor's action dt steps into a timing of T steps,

        beta(T, dt) = 1/2 (tanh(w (dt / T - 1/2)) / tanh(w / 2) + 1),   dt = 1, ..., T,

    with w = omega the shape coefficient [-] (the project's is 6, tarl.TimingConfig.omega). With dt = 1 it
    is the timing factor beta(T) = beta(T, 1) of Eq. (11).

    T, dt [steps]: numbers or arrays that broadcast against each other. Returns an array of their
    broadcast shape (a 0-d array for two numbers). Vectorise: no Python loop.
    """
    # TODO(student): Eq. (6)
    raise NotImplementedError("Eq. (6)")


def blend(a, a_base, b):
    """Eqs. (7) and (12): the executed action a_bar = beta a + (1 - beta) a_base.

    a: the actor's action, a_base: the planner's base action [m/s^2], b: beta. Numbers or arrays
    that broadcast; returns their broadcast shape.
    """
    # TODO(student): Eqs. (7), (12)
    raise NotImplementedError("Eqs. (7), (12)")


def discounted_sum(rewards, gamma):
    """Eq. (8): the reward of one timing decision, r_T = sum_{dt=1..T} gamma^(dt-1) r_dt.

    rewards: the T step rewards r_1, ..., r_T of the decision, in order (a list or a (T,) array);
    gamma: the discount factor. Returns a float.
    """
    # TODO(student): Eq. (8)
    raise NotImplementedError("Eq. (8)")
