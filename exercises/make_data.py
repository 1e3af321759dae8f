"""Store the answers the checker compares with: exercises/data/exN.npz, from the project's functions,
and data/in_vivo.json, the project's own run of the in-vivo cases (in_vivo.py).

    python -m exercises.make_data        # from the repository's root, with tarl, world, planner in place
    python -m exercises.make_data --out /tmp/data --cases 2    # elsewhere, a short in-vivo reference

Run it once (and again if the project's reference changes: tests/test_exercises.py says so). The checker
reads only the stored arrays, so a course may then blank the reference bodies. Inputs are random with
fixed seeds; every function is called the way the project calls it.
"""
from __future__ import annotations

import argparse
import json
import math
from dataclasses import asdict
from pathlib import Path

import numpy as np

from exercises.common import CFG, GAMMA, K1, OMEGA

DATA = Path(__file__).resolve().parent / "data"


def check_constants():
    """The constants copied into exercises/common.py are still the project's."""
    import planner
    import world
    env = world.EnvConfig()
    for field, value in asdict(CFG).items():
        assert getattr(env, field) == value, f"exercises.common.CFG.{field} = {value}, world.EnvConfig: {getattr(env, field)}"
    assert env.planner().K1 == K1 and planner.PlannerConfig.K1 == K1


def ex1() -> dict:
    import tarl
    assert tarl.TimingConfig().omega == OMEGA
    rng = np.random.default_rng(1)
    T = np.repeat(np.arange(1, 13), np.arange(1, 13))  # every (T, dt), dt = 1..T, T = 1..12
    dt = np.concatenate([np.arange(1, t + 1) for t in range(1, 13)])
    omegas = np.array([1.0, 3.0, 6.0, 10.0])
    a, a_base, b = rng.uniform(-3.0, 2.0, 50), rng.uniform(-3.0, 2.0, 50), rng.uniform(0.0, 1.0, 50)
    lengths, gammas = rng.integers(1, 11, 40), rng.choice([0.9, 0.99], 40)
    rewards = rng.uniform(-0.1, 0.5, (40, 10))
    rewards[::3, -1] = 20.0
    return dict(beta_T=T, beta_dt=dt, omegas=omegas, beta=np.stack([tarl.beta(T, dt, omega=w) for w in omegas]),
                blend_a=a, blend_a_base=a_base, blend_b=b, blend=tarl.blend(a, a_base, b),
                sum_rewards=rewards, sum_lengths=lengths, sum_gammas=gammas,
                sum=np.array([tarl.discounted_sum(r[:k], g) for r, k, g in zip(rewards, lengths, gammas)]))


def ex2() -> dict:
    import world
    cfg, rng = world.EnvConfig(), np.random.default_rng(2)
    phi = rng.uniform(-180.0, 180.0, 1000)
    index, moved = world.sector_index(phi)
    out = dict(sector_phi=phi, sector_index=index, sector_moved=moved)
    scenes = []
    for k in range(24):
        m = int(rng.integers(0, 26))
        ego_xy, heading = rng.uniform(-50.0, 50.0, 2), rng.uniform(-math.pi, math.pi)
        bearing, r = rng.uniform(-math.pi, math.pi, m), rng.uniform(2.0, 80.0, m)
        others = np.column_stack([ego_xy[0] + r * np.cos(bearing), ego_xy[1] + r * np.sin(bearing),
                                  rng.uniform(0.0, 14.0, m), rng.uniform(-2 * math.pi, 2 * math.pi, m),
                                  rng.uniform(-0.5, 0.5, m)])  # x, y, speed, heading, yaw rate (as DrivingEnv)
        scene = dict(ego_xy=ego_xy, ego_heading=heading, ego_speed=rng.uniform(0.0, 14.0),
                     task=int(rng.integers(3)), zone=int(rng.integers(3)), others=others)
        scenes.append(scene)
        out.update({f"scene{k}_{key}": value for key, value in scene.items()})
        out[f"scene{k}_obs"] = world.observe(**scene, cfg=cfg)
    out["scenes"] = len(scenes)
    cases = [(arrived, collided, v, lo, hi) for arrived in (False, True) for collided in (False, True)
             for v in (0.0, 0.5, 1.0, 3.7, 10.0, 13.0) for lo, hi in ((1.0, 10.0), (2.0, 6.0))]
    out["reward_cases"] = np.array(cases, dtype=float)
    out["reward"] = np.array([world.reward(*case) for case in cases])
    return out


def ex3() -> dict:
    import planner
    import world
    cfg, rng = world.EnvConfig().planner(), np.random.default_rng(3)
    n = 300
    args = (rng.uniform(-50, 50, n), rng.uniform(0, 15, n), rng.uniform(-3, 2, n), rng.uniform(-50, 150, n),
            rng.uniform(0, 15, n), rng.choice([0.0, 0.0, -1.0, 0.5], n), rng.uniform(0.5, 8.0, n))
    grid = (0.0, np.arange(3.0)[:, None], 0.5, 10.0, np.arange(4.0), 0.0, 2.0)  # broadcasts to (3, 4)
    # costs of 10 candidates (6 drive, 4 stop): the other terms < 10, K1 more for a collision, inf infeasible
    bad = rng.random((200, 10)) < rng.uniform(0.3, 0.95, (200, 1))
    costs = rng.uniform(0.5, 9.0, (200, 10)) + np.where(bad, rng.choice([K1, np.inf], (200, 10)), 0.0)
    drive_ids, stop_ids = slice(0, 6), slice(6, 10)
    fsm = [planner.state_machine(c, drive_ids, stop_ids, K1) for c in costs]
    l_dd, a_idm = rng.uniform(-5.0, 4.0, 200), rng.choice([np.inf, 1.0], 200) * rng.uniform(-9.0, 3.0, 200)
    return dict(quintic_args=np.array(args), quintic=planner.quintic_coefficients(*args),
                quintic_grid=planner.quintic_coefficients(*grid),
                fsm_cost=costs, fsm_mode=np.array([["drive", "stop", "brake"].index(m) for m, _ in fsm]),
                fsm_index=np.array([-1 if i is None else i for _, i in fsm]),
                base_l_dd=l_dd, base_a_idm=a_idm,
                base=np.array([planner.base_acceleration(x, y, cfg) for x, y in zip(l_dd, a_idm)]))


def ex4() -> dict:
    import world
    cfg, rng = world.EnvConfig(), np.random.default_rng(4)
    lo, hi = (np.array([world.HUMAN_RANGES[f"alpha{i}"][k] for i in range(1, 5)]) for k in (0, 1))
    n = 500
    alpha = rng.uniform(lo, hi, (n, 4))
    u_args = (rng.uniform(-1, 8, n), rng.uniform(0, 15, n), rng.uniform(-0.2, 1.5, n), rng.uniform(0, 45, n))
    o_args = (rng.uniform(0, 12, n), rng.uniform(0, 12, n), rng.uniform(0, 1.5, n), rng.choice([0.0, 5.0, 40.0], n),
              rng.integers(0, 2, n), rng.integers(0, 2, n))
    out = dict(utility_alpha=alpha, utility_args=np.array(u_args), utility=world.game_utility(alpha, *u_args, cfg),
               outcome_args=np.array(o_args), outcome=np.array(world.outcome_terms(*o_args, cfg)))
    for b, waited_e in enumerate((0.0, 35.0)):  # level 2 on random games, a third of them exact arrival ties
        m = 1500
        t_h, t_e = rng.uniform(0, 12, m), rng.uniform(0, 12, m)
        t_e[::3] = t_h[::3]
        game = dict(t_h=t_h, t_e=t_e, decel_h=rng.uniform(0, 1.5, m), decel_e=rng.uniform(0, 1.5, m),
                    waited_h=rng.choice([0.0, 5.0, 40.0], m), waited_e=waited_e,
                    alpha_h=rng.uniform(lo, hi, (m, 4)), svo=rng.uniform(*world.HUMAN_RANGES["svo"], m))
        out.update({f"game{b}_{key}": value for key, value in game.items()})
        out[f"game{b}_decision"] = world.level_k_decisions(**game, cfg=cfg)
    return out


def ex5() -> dict:
    import torch

    import tarl
    assert tarl.SACConfig().gamma == GAMMA
    rng, B, n = np.random.default_rng(5), 64, tarl.TimingConfig().t_max
    # decisions as Trainer.imagination_loop stores them: D_T.add(..., discounted_sum(rewards, gamma),
    # ..., gamma ** len(rewards), terminated): k < T steps when the episode ended inside the decision
    rewards, lengths, terminated, truncated = np.zeros((B, n)), np.zeros(B, int), np.zeros(B), np.zeros(B)
    for b in range(B):
        T, end = int(rng.integers(1, n + 1)), rng.choice(["none", "arrival", "collision", "timeout"])
        k = T if end == "none" else int(rng.integers(1, T + 1))
        rewards[b, :k] = rng.uniform(-0.06, 0.5, k)
        rewards[b, k - 1] = {"arrival": 20.0, "collision": -20.0}.get(end, rewards[b, k - 1])
        lengths[b], terminated[b], truncated[b] = k, end in ("arrival", "collision"), end == "timeout"
    # every third terminal on the time limit's last step too: both flags, as Gymnasium allows (DrivingEnv reports
    # such a step as terminated only), and a terminal all the same (done = terminated)
    truncated[np.flatnonzero(terminated)[::3]] = 1.0
    r_T = np.array([tarl.discounted_sum(r[:k], GAMMA) for r, k in zip(rewards, lengths)])
    discount, done = GAMMA ** lengths.astype(float), terminated.copy()
    # Eq. (9)'s target, tarl.td_target's discrete branch, on a small timing taker
    torch.manual_seed(5)
    agent = tarl.SAC(8, n_actions=n, cfg=tarl.SACConfig(hidden=32))
    with torch.no_grad():
        agent.log_alpha.fill_(math.log(0.2))
        agent.critic_target.w3.mul_(20.0)  # Q of a few units, as after training, not ~0.1
    batch = {"next_obs": torch.randn(B, 8), "rew": torch.as_tensor(r_T, dtype=torch.float32),
             "discount": torch.as_tensor(discount, dtype=torch.float32), "done": torch.as_tensor(done, dtype=torch.float32)}
    y = tarl.td_target(agent, batch)
    with torch.no_grad():
        probs, log_probs = agent.timing_distribution(batch["next_obs"])
        q_next = agent.critic_target(batch["next_obs"])
    return dict(rewards=rewards, lengths=lengths, terminated=terminated, truncated=truncated,
                r_T=r_T, discount=discount, done=done,
                rew32=batch["rew"].numpy(), discount32=batch["discount"].numpy(), done32=batch["done"].numpy(),
                q_next=q_next.numpy(), probs=probs.numpy(), log_probs=log_probs.numpy(),
                alpha=float(agent.log_alpha.detach().exp()), y=y.numpy())


BUILD = {1: ex1, 2: ex2, 3: ex3, 4: ex4, 5: ex5}


def main(argv=None):
    from exercises import in_vivo
    p = argparse.ArgumentParser(prog="python -m exercises.make_data", description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, default=DATA, help="where to write (default exercises/data)")
    p.add_argument("--cases", type=int, default=in_vivo.CASES, help="test cases of the in-vivo reference")
    args = p.parse_args(argv)
    check_constants()
    args.out.mkdir(parents=True, exist_ok=True)
    for n, build in BUILD.items():
        np.savez_compressed(args.out / f"ex{n}.npz", **build())
        print(f"wrote {args.out / f'ex{n}.npz'}")
    reference = in_vivo.reference_cases(args.cases)
    cases = ",\n  ".join(json.dumps(case) for case in reference.pop("cases"))  # one case a line
    (args.out / in_vivo.REFERENCE.name).write_text(json.dumps(reference)[:-1] + f', "cases": [\n  {cases}]}}\n')
    print(f"wrote {args.out / in_vivo.REFERENCE.name}")


if __name__ == "__main__":
    main()
