"""Bug hunt: the ego's observation, Eqs. (27)-(30), with ONE silent bug.

This is a copy of world.observe and the helpers it uses (SECTORS, wrap_angle, sector_index), with the
same signature, so that it can stand in for world.observe. One line in it is wrong. The shapes are
right, every number is finite and in range, nothing raises: a policy fed these observations still
drives. Run the shipped policy with it and without it and compare (EXERCISES.md, B), then find the
line by reading and probing it: place vehicles around an ego and look where they land. Don't diff it
against world.py. Fix it here; `python -m exercises.check bughunt` passes once it is fixed.
"""
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
    """Eq. (28)'s sector of position angles phi [deg]: k with PHI_LOW[k] < phi <= PHI_HIGH[k], and phi
    moved into (-150, 210]. Rounded to 1e-9 deg, so that a vehicle on a boundary lands where the
    half-open interval says despite atan2's round-off."""
    phi = np.asarray(phi_deg, dtype=float)
    rounded = np.round(phi, 9)
    rounded, phi = (np.where(rounded <= -150.0, x + 360.0, x) for x in (rounded, phi))
    return np.argmax((PHI_LOW < rounded[..., None]) & (rounded[..., None] <= PHI_HIGH), axis=-1), phi


def observe(ego_xy, ego_heading, ego_speed, task, zone, others, cfg) -> np.ndarray:
    """Eqs. (27)-(30): s = (s_ego, s_sur), 67 numbers. ego_xy [m] centre, ego_heading [rad, CCW from +x],
    ego_speed [m/s]; task, zone: indices of the one-hots h1, h2; others (M, >= 4): centre x, y [m],
    speed [m/s], heading [rad]; cfg: world.EnvConfig (perception = d_max, v_norm = v_max of Eq. (27))."""
    s_sur = np.zeros((6, 2, 5))
    rel = ego_xy - others[:, :2]
    d = np.hypot(rel[:, 0], rel[:, 1])
    seen = d <= cfg.perception
    rel, d, o = rel[seen], d[seen], others[seen]
    bearing = np.arctan2(rel[:, 1], rel[:, 0])  # [rad] the direction of each vehicle from the ego
    # Eq. (28): the position angle between the ego's heading and the vehicle [deg], and its sector
    sector, phi = sector_index(np.degrees(wrap_angle(bearing - ego_heading)))
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
