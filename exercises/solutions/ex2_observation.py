"""Solution of exercise 2: what the ego sees and earns. Equal to world.sector_index, world.observe, world.reward."""
import numpy as np

# Eq. (28): each sector is a half-open interval (phi_low, phi_high] [deg] of the position angle
# relative to the ego's heading, in this order in s_sur. The rear sector wraps: it is (150, 210].
SECTORS = (("front", -30.0, 30.0), ("left front", 30.0, 90.0), ("right front", -90.0, -30.0),
           ("left rear", 90.0, 150.0), ("right rear", -150.0, -90.0), ("rear", 150.0, 210.0))
SECTOR_NAMES = tuple(name for name, _, _ in SECTORS)
PHI_LOW, PHI_HIGH = (np.array([s[k] for s in SECTORS]) for k in (1, 2))


def wrap_angle(x):
    """Angle(s) [rad] wrapped into (-pi, pi]."""
    return np.pi - np.mod(np.pi - x, 2.0 * np.pi)


def sector_index(phi_deg):
    """Eq. (28): (k with PHI_LOW[k] < phi <= PHI_HIGH[k], phi moved into (-150, 210]), compared at 1e-9 deg."""
    phi = np.asarray(phi_deg, dtype=float)
    rounded = np.round(phi, 9)
    rounded, phi = (np.where(rounded <= -150.0, x + 360.0, x) for x in (rounded, phi))
    return np.argmax((PHI_LOW < rounded[..., None]) & (rounded[..., None] <= PHI_HIGH), axis=-1), phi


def observe(ego_xy, ego_heading, ego_speed, task, zone, others, cfg):
    """Eqs. (27)-(30): s = (s_ego, s_sur), 67 numbers."""
    s_sur = np.zeros((6, 2, 5))
    rel = others[:, :2] - ego_xy
    d = np.hypot(rel[:, 0], rel[:, 1])
    seen = d <= cfg.perception
    rel, d, o = rel[seen], d[seen], others[seen]
    # Eq. (28): the position angle [deg] relative to the ego's heading, counter-clockwise, and its sector
    sector, phi = sector_index(np.degrees(wrap_angle(np.arctan2(rel[:, 1], rel[:, 0]) - ego_heading)))
    order = np.lexsort((d, sector))  # by sector, then nearest first
    sector, d, phi, o = sector[order], d[order], phi[order], o[order]
    rank = np.arange(len(sector)) - np.searchsorted(sector, sector, side="left")
    keep = rank < 2  # Eq. (28): the two nearest per sector, j = 1, 2
    i, j = sector[keep], rank[keep]
    # Eq. (27): d / d_max, v / v_max, (phi - phi_low) / (phi_high - phi_low), (theta - theta_ego + pi) / 2 pi
    s_sur[i, j, 0] = 1.0
    s_sur[i, j, 1] = d[keep] / cfg.perception
    s_sur[i, j, 2] = o[keep, 2] / cfg.v_norm
    s_sur[i, j, 3] = (phi[keep] - PHI_LOW[i]) / (PHI_HIGH[i] - PHI_LOW[i])
    s_sur[i, j, 4] = (wrap_angle(o[keep, 3] - ego_heading) + np.pi) / (2.0 * np.pi)
    # Eq. (29): s_ego = (h1, h2, v_ego / v_max)
    s_ego = np.zeros(7)
    s_ego[[task, 3 + zone]] = 1.0
    s_ego[6] = ego_speed / cfg.v_norm
    # Eq. (30): s = (s_ego, s_sur)
    return np.concatenate([s_ego, s_sur.ravel()]).astype(np.float32)


def reward(arrived, collided, v, v_min, v_max):
    """Eq. (31): +20 on arrival, -20 on collision, else min((v - v_min) / (v_max - v_min), 1) x 0.5."""
    if collided:
        return -20.0
    return 20.0 if arrived else min((v - v_min) / (v_max - v_min), 1.0) * 0.5
