"""Exercise 5: the timing taker's critic target (paper Sec. 4, Eqs. (8)-(9), Algorithm 1 lines 7-13).

One decision of the timing imagination plays the actor's action over T steps (Eq. (7)), collects the
step rewards and stores one transition ((s, a), T, r_T, s', discount, delta) in D_T. The episode may
end before the T steps are over: by arrival or collision (a true terminal: nothing follows), or by the
60 s time limit (not a terminal: the world goes on, the agent just stopped watching). Let k <= T be the
number of steps actually played.

The critic Q(s, a, T) then regresses onto Eq. (9) with SAC's soft value (PAPER.md, notes 2 and 7),
taking the expectation over the next timing T' exactly (the head is discrete):

    y = r_T + gamma^k (1 - delta) sum_T' pi(T'|s') [min_i Q-hat_i(s', a', T') - alpha log pi(T'|s')]

Fill in the two TODO(student) blocks (numpy), then:    python -m exercises.check 5
Don't read tarl.py's td_target and Trainer.imagination_loop before you are done: they are the answer.
"""
import numpy as np


def timing_transition(rewards, gamma, terminated, truncated):
    """One decision -> (r_T, discount, done), the numbers D_T stores for it.

    rewards: the k step rewards actually received (k = T, or fewer if the episode ended); gamma: the
    discount factor; terminated: the episode ended by arrival or collision; truncated: by the time limit.
    Both may be true at once (Gymnasium allows it: an arrival or a collision on the step the time runs out).
    r_T: Eq. (8) over the k rewards; discount: what multiplies the next state's value in Eq. (9);
    done: delta of Eq. (9), 1.0 or 0.0. Returns three floats.
    """
    # TODO(student): Eqs. (8)-(9)
    raise NotImplementedError("Eqs. (8)-(9)")


def timing_td_target(r_T, discount, done, q_next, probs, log_probs, alpha):
    """Eq. (9): the target y (B,) of a batch of B decisions.

    r_T, discount, done (B,): from timing_transition; q_next (2, B, n): the two target critics
    Q-hat_1, Q-hat_2 at (s', a') for each of the n timings T' = 1..n (column T' - 1); probs, log_probs
    (B, n): pi(T'|s') and its log; alpha: the temperature, a float.
    """
    # TODO(student): Eq. (9)
    raise NotImplementedError("Eq. (9)")
