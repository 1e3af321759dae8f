"""Exercise 2: what the ego sees and earns (paper Sec. 5.2, Eqs. (27)-(31), Fig. 4).

The ego sees every vehicle within d_max = 60 m. Around it the plane is cut into six sectors by the
position angle phi of a vehicle relative to the ego's heading (counter-clockwise, in degrees: +90 is
straight to the ego's left). Each sector is a half-open interval (phi_low, phi_high] (Eq. (28)):

    front (-30, 30], left front (30, 90], right front (-90, -30], left rear (90, 150],
    right rear (-150, -90], rear (-180, -150] u (150, 180] = (150, 210] once phi <= -150 is moved up by 360.

Per sector, the two nearest vehicles give a 5-tuple each (Eq. (28)), normalised by Eq. (27); the ego's
own part (Eq. (29)) and the whole observation (Eq. (30)) follow. The step reward is Eq. (31).

Fill in the TODO(student) blocks (numpy), then:    python -m exercises.check 2
Read docs/PAPER.md, note 12 (the heading term and the rear sector). Don't read world.py's sector_index,
observe and reward before you are done: they are the answer.
"""
import numpy as np

# Eq. (28): the sectors (name, phi_low, phi_high) [deg], in their order in s_sur. The rear one wraps.
SECTORS = (("front", -30.0, 30.0), ("left front", 30.0, 90.0), ("right front", -90.0, -30.0),
           ("left rear", 90.0, 150.0), ("right rear", -150.0, -90.0), ("rear", 150.0, 210.0))
SECTOR_NAMES = tuple(name for name, _, _ in SECTORS)
PHI_LOW, PHI_HIGH = (np.array([s[k] for s in SECTORS]) for k in (1, 2))  # (6,) each [deg]


def wrap_angle(x):
    """Angle(s) [rad] wrapped into (-pi, pi] (given)."""
    return np.pi - np.mod(np.pi - x, 2.0 * np.pi)


def sector_index(phi_deg):
    """Eq. (28)'s sector of position angles phi [deg] in (-180, 180]: (index, phi moved).

    index: k with PHI_LOW[k] < phi <= PHI_HIGH[k], an int array of phi's shape; phi moved: phi, plus
    360 where phi <= -150 (so that it lies in (-150, 210] and the rear sector is (150, 210]).
    Decide both on phi rounded to 1e-9 deg (np.round(phi, 9)): a vehicle placed on a boundary comes
    out of atan2 a hair to either side of it, and must still land where the half-open interval says.
    Return the moved phi itself, not its rounded value. Vectorise: phi may be an array of any shape.
    """
    # TODO(student): Eq. (28)
    raise NotImplementedError("Eq. (28)")


def observe(ego_xy, ego_heading, ego_speed, task, zone, others, cfg):
    """Eqs. (27)-(30): the observation s = (s_ego, s_sur), 67 numbers (float32).

    ego_xy (2,) [m] the ego's centre; ego_heading [rad, counter-clockwise from +x]; ego_speed [m/s];
    task, zone: the indices (0..2 each) of the one-hots h1 and h2; others (M, >= 4): each vehicle's
    centre x, y [m], speed [m/s], heading [rad]; cfg: cfg.perception = d_max [m], cfg.v_norm = v_max of
    Eq. (27) [m/s].

    s_sur (6, 2, 5): sector i, its j-th nearest vehicle, (presence, d_hat, v_hat, phi_hat, theta_hat);
    zeros where a sector has fewer than two vehicles. s_ego (7,) = (h1 (3), h2 (3), v_ego / v_max).
    """
    s_sur = np.zeros((6, 2, 5))
    rel = others[:, :2] - ego_xy  # (M, 2) [m] from the ego to each vehicle
    d = np.hypot(rel[:, 0], rel[:, 1])  # (M,) [m]
    seen = d <= cfg.perception
    rel, d, o = rel[seen], d[seen], others[seen]
    # TODO(student): Eq. (28): phi, the position angle [deg] of each seen vehicle relative to the ego's
    # heading, wrapped into (-180, 180] (wrap_angle works in radians), and its sector:
    #     sector, phi = sector_index(...)
    raise NotImplementedError("the position angle phi and its sector")
    order = np.lexsort((d, sector))  # by sector, then nearest first (given from here to `keep`)
    sector, d, phi, o = sector[order], d[order], phi[order], o[order]
    rank = np.arange(len(sector)) - np.searchsorted(sector, sector, side="left")  # 0: nearest in its sector
    keep = rank < 2  # Eq. (28): the two nearest per sector, j = 1, 2
    i, j = sector[keep], rank[keep]
    # TODO(student): Eq. (27) into s_sur[i, j, 0..4] for the kept vehicles: presence 1,
    # d / d_max, v / v_max, (phi - phi_low) / (phi_high - phi_low) with the sector's bounds,
    # (theta - theta_ego + pi) / (2 pi) with theta - theta_ego wrapped into (-pi, pi] first.
    raise NotImplementedError("Eq. (27): the 5-tuples of s_sur")
    # TODO(student): Eq. (29): s_ego = (h1, h2, v_ego / v_max), then Eq. (30)
    raise NotImplementedError("Eqs. (29)-(30): s_ego and s")


def reward(arrived, collided, v, v_min, v_max):
    """Eq. (31): the step reward: +20 when the ego arrives, -20 when it collides, otherwise

        min((v - v_min) / (v_max - v_min), 1) x 0.5,

    v the ego's speed [m/s], v_min, v_max [m/s] the desired speed range (the project: 1 and 10 m/s).
    A collision is never an arrival. Returns a float.
    """
    # TODO(student): Eq. (31)
    raise NotImplementedError("Eq. (31)")
