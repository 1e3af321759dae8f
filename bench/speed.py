"""How fast is a training step? Both halves of it, measured side by side in one run.

    python bench/speed.py                 # a table
    python bench/speed.py --json          # the same numbers as one JSON object
    python bench/speed.py --quick         # fewer repetitions (a smoke test, noisier)

(a) SAC updates per second at the paper's sizes (Table 2: batch 256, two hidden layers of 256,
    observation 67, twin critics, automatic temperature): tarl.SAC.update against the plain
    reference update of bench/plain_sac.py, written the usual way (separate critic modules, separate
    standard Adam optimizers, critic step before policy step, a per-parameter soft-update loop) and
    equal to tarl.SAC's update (tests/test_sac.py checks it), for the actor's continuous SAC and the timing
    taker's discrete SAC. Also the machine's matrix-multiply peak and the FLOPs of one update
    (counted by torch), so the ceiling peak / FLOPs is known.
(b) Environment steps per second on each scenario: bare SUMO stepping (simulationStep alone, the
    humans still spawning, no ego) against the full environment step (SUMO, its queries, the
    observation, the base planner, the level-k game, the collision check); the time SUMO's step
    takes inside the full step, and the rest: the project's own work per step. Beside them, in the
    same blocks, the cost of a frame: env.render() (render_mode "rgb_array", 480 x 480 px, scene.py)
    after each full step, its snapshot of the scene included, also as a ratio to an env step.
(c) Base-planner calls per second on the states met in (b), and candidates per call.
(d) Training steps per second: Algorithm 1 on the roundabout, in step 1 (plain SAC, one update
    per step) and in the imagination + actor loops (an update per actor step and per timing
    decision), and what that makes of the paper's 5 x 10^5 steps; and the on-policy rows of
    baselines.py (PPO-Lag, CPO): rollouts of N steps, each followed by its update, per second.

The machine is shared and its speed drifts: variants run in alternating blocks and the report
gives medians (rates) and the median of the per-round paired ratios.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "bench")]
import tarl  # noqa: E402  (before torch: torch's threads then wait as they do in training)
import baselines  # noqa: E402
import experiment  # noqa: E402
import numpy as np  # noqa: E402
import planner  # noqa: E402
import torch  # noqa: E402
from plain_sac import PlainSAC  # noqa: E402
from tarl import SAC, SACConfig  # noqa: E402
from torch.utils.flop_counter import FlopCounterMode  # noqa: E402
import world  # noqa: E402

OBS_DIM, LOW, HIGH = world.OBS_DIM, -3.0, 2.0  # the observation; the actor's bounds [m/s^2]
T_MAX = 10  # the paper's T_max: the timing taker's choices T = 1..10, the discrete head's size
med = statistics.median


# ---- (a) SAC ------------------------------------------------------------------------------

def random_batches(n, obs_dim, discrete, batch_size=256, seed=0):
    g = torch.Generator().manual_seed(seed)
    out = []
    for _ in range(n):
        if discrete:
            act = torch.randint(1, T_MAX + 1, (batch_size,), generator=g)
            discount = 0.99 ** act.float()
        else:
            act = torch.rand(batch_size, 1, generator=g) * (HIGH - LOW) + LOW
            discount = torch.full((batch_size,), 0.99)
        out.append({"obs": torch.randn(batch_size, obs_dim, generator=g), "act": act,
                    "rew": torch.randn(batch_size, generator=g),
                    "next_obs": torch.randn(batch_size, obs_dim, generator=g),
                    "discount": discount, "done": (torch.rand(batch_size, generator=g) < 0.05).float()})
    return out


def rate(update, batches, k):
    start = time.perf_counter()
    for i in range(k):
        update(batches[i % len(batches)])
    return k / (time.perf_counter() - start)


def paired(fast, plain, batches, rounds, k):
    """Alternating blocks of k updates; medians of the rates and of the per-round ratios."""
    for _ in range(20):  # warm-up
        fast.update(batches[0])
        plain.update(batches[0])
    fast_rates, plain_rates = [], []
    for r in range(rounds):
        order = [(fast, fast_rates), (plain, plain_rates)]
        for agent, rates in order if r % 2 == 0 else order[::-1]:
            rates.append(rate(agent.update, batches, k))
    return med(fast_rates), med(plain_rates), med(f / p for f, p in zip(fast_rates, plain_rates))


def matmul_gflops(n=1024, k=100):
    """The machine's float32 matrix-multiply rate [GFLOP/s] with torch's present threads (best of 5)."""
    a, b = torch.randn(n, n), torch.randn(n, n)
    for _ in range(5):
        a @ b
    best = 0.0
    for _ in range(5):
        start = time.perf_counter()
        for _ in range(k // 5):
            a @ b
        best = max(best, 2 * n**3 * (k // 5) / (time.perf_counter() - start) / 1e9)
    return best


def update_gflop(agent, batch) -> float:
    with FlopCounterMode(display=False) as counter:
        agent.update(batch)
    return counter.get_total_flops() / 1e9


def sac_section(rounds, k) -> dict:
    cfg = SACConfig()
    actor = SAC(OBS_DIM, act_dim=1, low=LOW, high=HIGH, cfg=cfg)
    plain = PlainSAC(OBS_DIM, act_dim=1, low=LOW, high=HIGH, cfg=cfg)
    batches = random_batches(8, OBS_DIM, False)
    fast_c, plain_c, ratio_c = paired(actor, plain, batches, rounds, k)
    timing = SAC(OBS_DIM + 1, n_actions=T_MAX, cfg=cfg)
    plain_t = PlainSAC(OBS_DIM + 1, n_actions=T_MAX, cfg=cfg)  # H_bar = target_entropy_fraction log 10, as tarl.SAC's
    fast_d, plain_d, ratio_d = paired(timing, plain_t, random_batches(8, OBS_DIM + 1, True), rounds, k)
    peak, flop = matmul_gflops(), update_gflop(actor, batches[0])
    return dict(sac_updates_per_s=fast_c, sac_plain_updates_per_s=plain_c, sac_ratio=ratio_c,
                timing_updates_per_s=fast_d, timing_plain_updates_per_s=plain_d, timing_ratio=ratio_d,
                matmul_gflops=peak, sac_gflop_per_update=flop, sac_ceiling_updates_per_s=peak / flop)


# ---- (b) environment, (c) planner ---------------------------------------------------------

def env_section(scenario, rounds, k, seed=1) -> tuple[dict, list]:
    """Alternating blocks of k full steps (the ego driven by the base planner) and k bare SUMO steps.

    A bare block takes the ego out (its episode ends) and steps the same running simulation with
    the humans spawning as before; the next full block puts a new ego in. Returns the numbers and
    the planner's inputs met in the full blocks.
    """
    env = world.DrivingEnv(world.EnvConfig(scenario=scenario), render_mode="rgb_array")
    sim, L = env.sim, env.cfg.length
    env.reset(seed=seed)
    frame = env.render()  # the renderer, made once: its background is drawn here, not in the frames timed
    full_t = bare_t = sumo_in_full = render_t = 0.0
    full_n = bare_n = 0
    full_veh, bare_veh, states = [], [], []
    step_sumo = sim.simulationStep

    def timed_sumo():  # SUMO's own step as called from inside env.step
        nonlocal sumo_in_full
        start = time.perf_counter()
        step_sumo()
        sumo_in_full += time.perf_counter() - start

    for _ in range(100):  # warm-up: the ego is on its way, the game is being played
        _, _, term, trunc, _ = env.step(env.base_action())
        if term or trunc:
            env.reset()
    for _ in range(rounds):
        sim.simulationStep = timed_sumo
        try:
            for _ in range(k):
                states.append((env.s - L / 2, env.v, env.accel, env.task["s"], env.task["xy"], env.others.copy(),
                               env.planner_cfg))
                start = time.perf_counter()
                _, _, term, trunc, _ = env.step(env.base_action())  # the full step, the planner included
                full_t += time.perf_counter() - start
                full_n += 1
                full_veh.append(sim.vehicle.getIDCount())
                start = time.perf_counter()
                env.render()  # a frame of the state the step left (after an episode's end, its last state)
                render_t += time.perf_counter() - start
                if term or trunc:
                    env.reset()
        finally:
            sim.simulationStep = step_sumo
        env._end_episode()
        for _ in range(k):
            env._spawn_humans()
            start = time.perf_counter()
            sim.simulationStep()
            bare_t += time.perf_counter() - start
            bare_n += 1
            bare_veh.append(sim.vehicle.getIDCount())
        env.reset()
    env.close()
    full_ms, bare_ms, sumo_ms = 1e3 * full_t / full_n, 1e3 * bare_t / bare_n, 1e3 * sumo_in_full / full_n
    render_ms = 1e3 * render_t / full_n
    return dict(env_steps_per_s=1e3 / full_ms, sumo_raw_steps_per_s=1e3 / bare_ms, env_to_raw_ratio=bare_ms / full_ms,
                env_ms=full_ms, sumo_in_env_ms=sumo_ms, own_ms=full_ms - sumo_ms, render_ms=render_ms,
                render_to_env_ratio=render_ms / full_ms, render_px=list(frame.shape[:2]),
                vehicles_full=float(np.mean(full_veh)), vehicles_bare=float(np.mean(bare_veh))), states


def planner_section(states, repeats) -> dict:
    times = []
    for _ in range(repeats):
        for s in states:
            start = time.perf_counter()
            planner.base_action(*s)
            times.append(time.perf_counter() - start)
    ms = 1e3 * np.array(times)
    return dict(planner_calls_per_s=1e3 / ms.mean(), planner_ms_mean=float(ms.mean()),
                planner_ms_p99=float(np.percentile(ms, 99)), planner_ms_max=float(ms.max()),
                planner_candidates=len(planner.lattice(states[0][-1]).te))


# ---- (d) training ---------------------------------------------------------------------------

def train_section(steps, warmup, rollout, time_limit=60.0) -> dict:
    """Steps/s of Trainer.run on the roundabout, with updates from the start (small N_start); of PPO-Lag and
    CPO over two rollouts of `rollout` steps and their updates (SafeRLConfig's N: 2,048)."""
    out = {}
    # a loop of Alg. 1 ends with its episode: --quick shortens episodes, or a few steps become hundreds
    env = world.DrivingEnv(world.EnvConfig(scenario="roundabout", time_limit=time_limit))
    sac_cfg = SACConfig(learning_starts=256)
    # plain SAC = Alg. 1 step 1 (the actor loop alone); TARL without its step 1: both loops
    for phase, timing in (("sac", "none"), ("tarl", "taker")):
        tc = tarl.TrainConfig(steps=warmup, timing_pretrain=0.05, timing_learning_starts=64,
                              log_every=10**9, checkpoint_every=10**9)
        trainer = tarl.Trainer(env, phase, tc, sac_cfg, log=lambda *a: None, timing=timing, step_one=False)
        trainer.run()  # warm-up: buffers past N_start, updates running
        trainer.tc = replace(tc, steps=trainer.step + steps)
        start, step0, updates = time.perf_counter(), trainer.step, dict(trainer.updates)
        trainer.run()  # it may run past its steps to finish a loop of Alg. 1: count what it ran
        elapsed, ran = time.perf_counter() - start, trainer.step - step0
        out[phase] = ran / elapsed
        out[phase + "_updates_per_step"] = sum(trainer.updates[k] - updates[k] for k in updates) / ran
    env.close()
    budget, share = 500_000, tarl.TrainConfig().sac_fraction  # Table 2's N_train; Alg. 1 step 1's share
    hours = budget * (share / out["sac"] + (1 - share) / out["tarl"]) / 3600
    for algo in ("ppo-lag", "cpo"):  # env-bound: a rollout of N steps, then one update on it
        env = world.DrivingEnv(world.EnvConfig(scenario="roundabout", time_limit=time_limit))
        tc = tarl.TrainConfig(steps=2 * rollout, log_every=10**9, checkpoint_every=10**9)
        trainer = baselines.OnPolicyTrainer(env, algo, tc, log=lambda *a: None, cfg=baselines.SafeRLConfig(rollout=rollout))
        start = time.perf_counter()
        trainer.run()
        out[algo] = trainer.step / (time.perf_counter() - start)
        env.close()
    return dict(train_steps_per_s=out["tarl"], train_sac_steps_per_s=out["sac"], train_ppo_lag_steps_per_s=out["ppo-lag"],
                train_cpo_steps_per_s=out["cpo"], train_rollout=rollout,
                train_updates_per_step=out["tarl_updates_per_step"],
                train_sac_updates_per_step=out["sac_updates_per_step"], paper_budget_hours=hours)


# ---- (e) test cases ----------------------------------------------------------------------------

def cases_section(n, rounds) -> dict:
    """What the fixed test cases cost on the roundabout: recording a round of n cases (the traffic alone,
    saved every case_gap s) and loading one, against what the former protocol paid instead: one restart
    with its warm-up per round, and nothing per case. The episodes themselves cost the same either way."""
    env = world.DrivingEnv(world.EnvConfig(scenario="roundabout"))
    record, load, restart = [], [], []
    with tempfile.TemporaryDirectory() as folder:
        for r in range(rounds):
            start = time.perf_counter()
            env._start(1000 + r)
            restart.append(time.perf_counter() - start)
            start = time.perf_counter()
            cases = env.record_cases(1000 + r, n, folder)
            record.append(time.perf_counter() - start)
            for case in cases[:: max(1, n // 10)]:
                start = time.perf_counter()
                env._load_case(case)
                load.append(time.perf_counter() - start)
    env.close()
    per_round = np.mean(record) + n * np.mean(load) - np.mean(restart)
    return dict(cases_record_s=float(np.mean(record)), cases_load_ms=1e3 * float(np.mean(load)),
                cases_restart_s=float(np.mean(restart)), cases_extra_s_per_round=float(per_round), cases_per_round=n)


# ---- report -----------------------------------------------------------------------------------

def machine() -> str:
    """experiment.machine(): the CPU type; and this process's torch threads and Python."""
    return f"{experiment.machine()}, {torch.get_num_threads()} torch threads, Python {platform.python_version()}"


def table(r) -> str:
    s = [f"machine: {r['machine']}",
         f"load average before: {r['load_before']}",
         "",
         "| what | this project | reference | ratio |",
         "|---|---|---|---|",
         f"| SAC update, actor (continuous) | {r['sac_updates_per_s']:.0f} /s | plain"
         f" {r['sac_plain_updates_per_s']:.0f} /s | {r['sac_ratio']:.2f}x |",
         f"| SAC update, timing taker (discrete) | {r['timing_updates_per_s']:.0f} /s | plain"
         f" {r['timing_plain_updates_per_s']:.0f} /s | {r['timing_ratio']:.2f}x |",
         f"| SAC ceiling: {r['sac_gflop_per_update']:.2f} GFLOP per update at {r['matmul_gflops']:.0f} GFLOP/s |"
         f" {r['sac_ceiling_updates_per_s']:.0f} /s | | {r['sac_updates_per_s'] / r['sac_ceiling_updates_per_s']:.2f}"
         " of it |"]
    for sc in ("intersection", "roundabout"):
        e = r["env"][sc]
        s.append(f"| env step, {sc} ({e['vehicles_full']:.0f} vehicles; bare {e['vehicles_bare']:.0f}) |"
                 f" {e['env_steps_per_s']:.0f} /s ({e['env_ms']:.2f} ms: SUMO {e['sumo_in_env_ms']:.2f},"
                 f" own work {e['own_ms']:.2f}) | bare SUMO {e['sumo_raw_steps_per_s']:.0f} /s |"
                 f" {e['env_to_raw_ratio']:.2f}x |")
    for sc in ("intersection", "roundabout"):
        e = r["env"][sc]
        s.append(f"| frame, {sc}: env.render(), {e['render_px'][1]} x {e['render_px'][0]} px | {e['render_ms']:.2f} ms"
                 f" ({1e3 / e['render_ms']:.0f} /s) | env step {e['env_ms']:.2f} ms | {e['render_to_env_ratio']:.1f} env steps |")
    s.append(f"| base planner, {r['planner_candidates']} candidates | {r['planner_calls_per_s']:.0f} calls/s"
             f" ({r['planner_ms_mean']:.3f} ms mean, {r['planner_ms_p99']:.3f} ms p99) | | |")
    s.append(f"| training, Alg. 1 step 1 ({r['train_sac_updates_per_step']:.2f} updates/step) |"
             f" {r['train_sac_steps_per_s']:.0f} steps/s | | |")
    s.append(f"| training, imagination + actor ({r['train_updates_per_step']:.2f} updates/step) |"
             f" {r['train_steps_per_s']:.0f} steps/s | | |")
    for algo, name in (("ppo_lag", "PPO-Lag"), ("cpo", "CPO")):
        s.append(f"| training, {name} (rollouts of {r['train_rollout']:,}, then an update) |"
                 f" {r[f'train_{algo}_steps_per_s']:.0f} steps/s | | |")
    s.append(f"| the paper's 5x10^5 steps (40 % step 1), extrapolated | {r['paper_budget_hours']:.2f} h | | |")
    s.append(f"| test cases, roundabout: record a round of {r['cases_per_round']}, load one | {r['cases_record_s']:.1f} s,"
             f" {r['cases_load_ms']:.1f} ms | a restart with warm-up {r['cases_restart_s']:.2f} s | +{r['cases_extra_s_per_round']:.1f}"
             " s per round |")
    return "\n".join(s)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    parser.add_argument("--quick", action="store_true", help="fewer repetitions: a smoke test, noisier")
    parser.add_argument("--threads", type=int, default=2, help="torch threads (the machine has 2 cores)")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    rounds, k = (2, 5) if args.quick else (10, 60)
    log = (lambda *a: print(*a, file=sys.stderr)) if args.json else print
    r = dict(machine=machine(), load_before=round(os.getloadavg()[0], 2))
    log("(a) SAC updates ...")
    r.update(sac_section(rounds, k))
    log("(b) environment steps ...")
    r["env"], states = {}, []
    for sc in ("intersection", "roundabout"):
        r["env"][sc], met = env_section(sc, 1 if args.quick else 4, 40 if args.quick else 250)
        states += met
    for key in ("env_steps_per_s", "sumo_raw_steps_per_s"):
        r[key] = {sc: r["env"][sc][key] for sc in r["env"]}
    log("(c) base planner ...")
    r.update(planner_section(states, 1 if args.quick else 3))
    log("(d) training steps ...")
    r.update(train_section(*((30, 280, 32, 6.0) if args.quick else (1500, 800, baselines.SafeRLConfig.rollout))))
    log("(e) test cases ...")
    r.update(cases_section(*((5, 1) if args.quick else (200, 3))))
    print(json.dumps(r, indent=1) if args.json else table(r))


if __name__ == "__main__":
    main()
