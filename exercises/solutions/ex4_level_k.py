"""Solution of exercise 4: the level-k humans. Equal to world.game_utility, world.outcome_terms,
world.level_k_decisions (level 2)."""
import numpy as np

CROSS, YIELD = 0, 1
EGO_GAME_WEIGHTS = np.array([0.65, 0.125, 0.125, 0.125])  # the ego as humans picture it: Table 1's middle


def game_utility(alpha, gap, wait, decel, waited, cfg):
    """Eq. (24), each term normalised by Eq. (25): U = a1 phi_safe - a2 phi_eff - a3 phi_comf + a4 phi_emo."""
    a = np.asarray(alpha)
    return (a[..., 0] * np.clip(gap / cfg.gap_range, 0.0, 1.0) - a[..., 1] * np.clip(wait / cfg.wait_range, 0.0, 1.0)
            - a[..., 2] * np.clip(decel, 0.0, 1.0) + a[..., 3] * np.clip(waited / cfg.emotion_range, 0.0, 1.0))


def outcome_terms(t_me, t_other, stop_decel, waited, me, other, cfg):
    """The four terms of Eq. (24) for a player choosing `me` against `other` (given in the exercise)."""
    both_yield = (me == YIELD) & (other == YIELD)
    t_mine = np.where((me == YIELD) & (other == CROSS), np.maximum(t_me, t_other + cfg.clear_time), t_me)
    t_theirs = np.where((other == YIELD) & (me == CROSS), np.maximum(t_other, t_me + cfg.clear_time), t_other)
    wait = np.where(both_yield, cfg.wait_range, t_mine - t_me)
    decel = np.where((me == YIELD) & (wait > 0), stop_decel, 0.0)
    return np.abs(t_mine - t_theirs), wait, decel, np.where(me == CROSS, waited, 0.0)


def level_k_decisions(t_h, t_e, decel_h, decel_e, waited_h, waited_e, alpha_h, svo, cfg):
    """Level-2 decisions (CROSS / YIELD, (M,)) of M humans against the ego."""
    m = np.arange(len(t_h))
    me, other = np.array([CROSS, YIELD]).reshape(2, 1, 1), np.array([CROSS, YIELD]).reshape(1, 2, 1)
    # Eq. (24) for every pair of choices: U_h[i, j] the human's utility when it plays i and the ego j,
    # U_e[i, j] the ego's when it plays i and the human j; (2, 2, M) each
    U_h = game_utility(alpha_h, *outcome_terms(t_h, t_e, decel_h, waited_h, me, other, cfg), cfg)
    U_e = game_utility(EGO_GAME_WEIGHTS, *outcome_terms(t_e, t_h, decel_e, waited_e, me, other, cfg), cfg)
    h0 = U_h[:, CROSS].argmax(0)  # level 0: the human against an ego that goes on
    e1 = U_e[:, h0, m].argmax(0)  # level 1: the ego against h0
    # Eq. (26): U_svo = (1 - a_svo) U_self + a_svo U_oppo, level 2 against e1
    U_svo = (1.0 - svo) * U_h[:, e1, m] + svo * U_e[e1, :, m].T
    return np.where(decel_h > 1.0, CROSS, U_svo.argmax(0))
