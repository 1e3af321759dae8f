"""Solution of exercise 5: the timing taker's critic target, Eq. (9). Equal to what Trainer.imagination_loop
stores in D_T and tarl.td_target computes from it (discrete branch)."""
import numpy as np


def timing_transition(rewards, gamma, terminated, truncated):
    """One decision of the timing imagination -> (r_T, discount, done) stored in D_T."""
    k = len(rewards)  # the steps actually played: T, or fewer if the episode ended
    r_T = float(np.sum(np.asarray(rewards) * gamma ** np.arange(k)))  # Eq. (8)
    # Eq. (9): discount gamma^k; delta = 1 only at a true terminal (arrival, collision), not at the time limit;
    # a terminal on the step the time runs out (both flags true) is a terminal all the same
    return r_T, gamma**k, float(terminated)


def timing_td_target(r_T, discount, done, q_next, probs, log_probs, alpha):
    """Eq. (9): y = r_T + gamma^k (1 - delta) sum_T' pi(T'|s') [min_i Q-hat_i(s', T') - alpha log pi(T'|s')]."""
    v_next = (probs * (np.min(q_next, axis=0) - alpha * log_probs)).sum(-1)  # the expectation over T' exactly
    return r_T + discount * (1.0 - done) * v_next
