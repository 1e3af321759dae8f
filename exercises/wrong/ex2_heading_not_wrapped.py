"""Wrong answer to exercise 2: Eq. (27)'s heading term with theta - theta_ego not wrapped, as printed
(PAPER.md, note 12): it leaves [0, 1] for some headings."""
import numpy as np

from exercises.solutions.ex2_observation import PHI_HIGH, PHI_LOW, reward, sector_index, wrap_angle  # noqa: F401

CHECKER_SAYS = "wrap theta - theta_ego into (-pi, pi] first"


def observe(ego_xy, ego_heading, ego_speed, task, zone, others, cfg):
    s_sur = np.zeros((6, 2, 5))
    rel = others[:, :2] - ego_xy
    d = np.hypot(rel[:, 0], rel[:, 1])
    seen = d <= cfg.perception
    rel, d, o = rel[seen], d[seen], others[seen]
    sector, phi = sector_index(np.degrees(wrap_angle(np.arctan2(rel[:, 1], rel[:, 0]) - ego_heading)))
    order = np.lexsort((d, sector))
    sector, d, phi, o = sector[order], d[order], phi[order], o[order]
    rank = np.arange(len(sector)) - np.searchsorted(sector, sector, side="left")
    keep = rank < 2
    i, j = sector[keep], rank[keep]
    s_sur[i, j, 0] = 1.0
    s_sur[i, j, 1] = d[keep] / cfg.perception
    s_sur[i, j, 2] = o[keep, 2] / cfg.v_norm
    s_sur[i, j, 3] = (phi[keep] - PHI_LOW[i]) / (PHI_HIGH[i] - PHI_LOW[i])
    s_sur[i, j, 4] = (o[keep, 3] - ego_heading + np.pi) / (2.0 * np.pi)  # the mistake: not wrapped
    s_ego = np.zeros(7)
    s_ego[[task, 3 + zone]] = 1.0
    s_ego[6] = ego_speed / cfg.v_norm
    return np.concatenate([s_ego, s_sur.ravel()]).astype(np.float32)
