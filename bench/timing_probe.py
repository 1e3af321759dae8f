"""Why the learned timing does not help: the ranking of T in the timing imagination and in the real loop,
from the same states.

T means different things in Algorithm 1's two loops. In the timing imagination a decision with T plays
the actor's a_t, held, for T steps and phases it in by Eq. (7): beta(T, dt) rises from ~0 to 1 over
dt = 1..T (sum (T + 1) / 2), so T = 10 is ~3 planner steps, 1 mixed, then 6 of a_t. In the real loop
(Eqs. (11)-(12)) T only sets the weight beta(T) of a fresh a_t at every step: T >= 4 is beta < 0.05,
the planner alone. The imagination never shows the timing taker what "let the planner drive" leads to.

This probe branches from states of evaluation rollouts of the shipped seed-0 TARL policy (round 0's
test cases of Table 3's protocol, played by TARL's driver deterministically): every --every steps, and
every --crash-every steps of the last 3 s before each collision among the first --crash-search cases.
From each state and each T = 1..T_max it runs
    imagination        one decision of Eq. (7): a_t = actor(s) (mean), held; beta(T, dt), dt = 1..T
    real               the real loop's blend for T steps: a fresh a_t each step, beta(T) of Eq. (11)
and after the T steps the same continuation for both, TARL's learned driver to the episode's end; and
    imagination-const  Eq. (7) decisions with this T to the end (the earlier probe's constant T)
    real-const         beta(T) every step to the end
    original           TARL's driver from the state: must reproduce the recorded episode (asserted)
Each branch: outcome, return and discounted return (gamma = 0.99) from the branch point, steps.

A state is restored by deterministic replay of the case's recorded executed actions from its start, not
by saveState/loadState (a loaded state does not continue exactly, docs/PAPER.md, Sec. 4); the replayed
observation must equal the recorded one bit for bit, and the "original" branch must end as the episode did.

    python bench/timing_probe.py --scenario both          # the defaults: 13 min beside two training runs
    python bench/timing_probe.py --scenario roundabout --cases 20 --every 10
    python bench/timing_probe.py --report                 # summary.md and ranking.png from the JSONs
    python bench/timing_probe.py --scenario intersection --critic runs/critic/intersection-tarl-s0/ckpt.pt
                                                          # and the timing taker's Q(s, a, T) at the same states
    python bench/timing_probe.py --scenario roundabout --algo tarl-actor-target   # a variant's own policy, then
    python bench/timing_probe.py --scenario roundabout --algo tarl-actor-target --critic runs/grid/roundabout-tarl-actor-target-s0/ckpt.pt

Writes results/timing_probe/{scenario}.json (every branch; {scenario}-{algo}.json for a variant of --algo),
summary.md and ranking.png (every JSON there).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import tarl  # noqa: E402, I001 (first: it sets OpenMP's wait policy before torch loads)
import experiment  # noqa: E402
import matplotlib  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
import world  # noqa: E402

matplotlib.use("Agg")

GAMMA = 0.99  # Table 2's gamma, for the discounted return
OUT = ROOT / "results" / "timing_probe"
LOOPS = ("imagination", "real", "imagination-const", "real-const")
WINDOW = 3.0  # [s] before a collision: Sec. 5.5's window
OUTCOMES = ("arrival", "collision", "timeout")


def load_tarl(env: world.DrivingEnv, scenario: str, path: Path | None = None, algo: str = "tarl"):
    """The shipped seed-0 policy of TARL (or of a variant with a timing taker, --algo): trainer.driver (learned
    timing), .actor, .timing_taker."""
    path = path or ROOT / "results" / "runs" / experiment.run_name(scenario, algo, 0) / "policy.pt"
    state = experiment.load_checkpoint(path, scenario, algo)
    tc = tarl.TrainConfig(timing=experiment.checkpoint_timing(state))
    trainer = experiment.make_trainer(algo, env, tc, 0, None, lambda *a: None, state=state)
    trainer.load(state, resume=False)
    return trainer


def blend_schedule(loop: str, T: int, j: int, omega: float) -> tuple[float, bool]:
    """Step j = 0, 1, ... after the branch point: (beta, whether a_t is drawn afresh from the actor)."""
    if loop.startswith("imagination"):
        dt = j % T + 1  # a new decision every T steps ("-const"); one decision for "imagination"
        return float(tarl.beta(T, dt, omega=omega)), dt == 1  # Eq. (7): beta(T, dt), a_t held over dt = 1..T
    return float(tarl.beta(T, omega=omega)), True  # Eqs. (11)-(12): beta(T_t), a fresh a_t every step


def drive(env, trainer, obs, loop: str = "original", T: int = 0, trace: list | None = None):
    """From the present state: `loop`'s blend (T steps, or to the end for "-const"), then TARL's learned
    driver (deterministic) to the episode's end. Returns the outcome, rewards, executed actions and the
    observation before each step; trace gets (a_t, beta, a_base or nan at beta = 1, a_bar) of each blended step."""
    n_blend = 0 if loop == "original" else T if loop in ("imagination", "real") else 10**9
    omega, rewards, actions, seen, a, done, j = trainer.driver.timing_cfg.omega, [], [], [], None, False, 0
    while not done:
        seen.append(obs)
        if j < n_blend:
            b, fresh = blend_schedule(loop, T, j, omega)
            a = trainer.actor.act(obs, deterministic=True) if fresh else a
            a_bar = tarl.execute(env, a, b)  # Eqs. (7), (12): beta a + (1 - beta) a_base (no planner at beta = 1)
            if trace is not None:
                trace.append((float(a[0]), b, env.base_action() if b < 1.0 else np.nan, a_bar))
        else:
            a_c, _, b_c = trainer.driver.act(obs, env, deterministic=True)
            a_bar = tarl.execute(env, a_c, b_c)
        obs, r, terminated, truncated, info = env.step(a_bar)
        rewards.append(r)
        actions.append(a_bar)
        done, j = terminated or truncated, j + 1
    end = "collision" if info["collision"] else "arrival" if info["arrival"] else "timeout"
    return dict(outcome=end, rewards=rewards, actions=actions, obs=seen)


def play(env, trainer, case: dict) -> dict:
    """A test case played by TARL's driver as experiment.rollout plays it, with each step's observation."""
    obs, _ = env.reset(options={"case": case})
    trainer.driver.new_episode(case["seed"])
    return drive(env, trainer, obs)


def restore(env, trainer, case: dict, ep: dict, k: int):
    """The state before step k of the recorded episode `ep`, by replaying its executed actions; checked."""
    obs, _ = env.reset(options={"case": case})
    trainer.driver.new_episode(case["seed"])
    for a_bar in ep["actions"][:k]:
        obs = env.step(a_bar)[0]
    assert np.array_equal(obs, ep["obs"][k]), f"replay of case {case['seed']} diverged before step {k}"
    return obs


def branch_steps(n_steps: int, every: int, collided: bool, crash_every: int, dt: float) -> list[tuple[int, str]]:
    """(k, kind) of the states to branch from: every `every` steps from the start, and every
    `crash_every` steps of the last WINDOW seconds before a collision (the collision is step n_steps)."""
    steps = [(k, "regular") for k in range(0, n_steps, every)] if every else []
    if collided and crash_every:
        steps += [(k, "crash") for k in range(max(0, n_steps - round(WINDOW / dt)), n_steps, crash_every)]
    return steps


def branch_record(res: dict, **keys) -> dict:
    return dict(keys, outcome=res["outcome"], ret=float(np.sum(res["rewards"])),
                disc=tarl.discounted_sum(res["rewards"], GAMMA), steps=len(res["rewards"]))


def probe(scenario: str, cases: int, every: int, crash_search: int, crash_cases: int, crash_every: int,
          t_max: int | None = None, log=print, critic: Path | None = None, algo: str = "tarl") -> dict:
    """Every branch of every state of `scenario`, with the wall time and the settings. critic: a ckpt.pt of the
    shipped run (policy.pt holds no critic): the states alone, with its timing taker's Q(s, a, T), no branch."""
    t0, env = time.time(), world.DrivingEnv(world.EnvConfig(scenario=scenario))
    try:
        trainer = load_tarl(env, scenario, algo=algo)
        if critic is not None:
            full = load_tarl(env, scenario, critic, algo)
            for net in ("actor", "timing_taker"):  # the same policies: the states are the shipped run's
                same = zip(getattr(full, net).policy.state_dict().values(), getattr(trainer, net).policy.state_dict().values())
                if not all(torch.equal(a, b) for a, b in same):
                    raise SystemExit(f"{critic}: its {net} is not the shipped policy.pt's")
            trainer = full
        t_max, cfg = t_max or trainer.driver.timing_cfg.t_max, env.cfg
        with tempfile.TemporaryDirectory() as folder:
            recorded = env.record_cases(experiment.test_seed(0, 0), max(cases, crash_search), folder)
            episodes = [play(env, trainer, case) for case in recorded]
            crashed = [c for c, ep in enumerate(episodes) if ep["outcome"] == "collision"][:crash_cases]
            states = [(c, k, kind) for c, ep in enumerate(episodes)
                      for k, kind in branch_steps(len(ep["actions"]), every * (c < cases), c in crashed,
                                                  crash_every, cfg.dt)]
            log(f"{scenario}: {len(recorded)} cases played ({time.time() - t0:.0f} s), {len(crashed)} collisions "
                f"used; {len(states)} states x {1 + len(LOOPS) * t_max} branches")
            out, t1 = dict(scenario=scenario, algo=algo, t_max=t_max, omega=trainer.driver.timing_cfg.omega, gamma=GAMMA,
                           cases=cases, every=every, crash_cases=crashed, states=[], branches=[]), time.time()
            for i, (c, k, kind) in enumerate(states):
                ep = episodes[c]
                obs = restore(env, trainer, recorded[c], ep, k)
                a = trainer.actor.act(obs, deterministic=True)
                x = torch.as_tensor(tarl.timing_input(obs, a, cfg))[None]
                with torch.no_grad():
                    pi = trainer.timing_taker.timing_distribution(x)[0][0].numpy()
                out["states"].append(dict(case=c, k=k, kind=kind, episode=ep["outcome"],
                                          episode_steps=len(ep["actions"]), taker_T=int(pi.argmax()) + 1,
                                          taker_pi=pi.round(4).tolist()))
                if critic is not None:  # the critics' view of the state, no branch
                    with torch.no_grad():
                        q = trainer.timing_taker.critic(x).amin(0)[0]  # min of the twin Q(s, a, T), Eq. (9)
                        q_actor = trainer.actor.critic(torch.as_tensor(obs)[None], torch.as_tensor(a)[None]).amin()
                    out["states"][-1].update(taker_q=q.numpy().round(4).tolist(), actor_q=round(float(q_actor), 4))
                    continue
                same = drive(env, trainer, obs)  # the control: TARL's own continuation
                assert (same["outcome"], same["rewards"]) == (ep["outcome"], ep["rewards"][k:]), \
                    f"case {c}, step {k}: the restored state does not continue as the recorded episode"
                out["branches"].append(branch_record(same, case=c, k=k, kind=kind, loop="original", T=0))
                for loop in LOOPS:
                    for T in range(1, t_max + 1):
                        res = drive(env, trainer, restore(env, trainer, recorded[c], ep, k), loop, T)
                        out["branches"].append(branch_record(res, case=c, k=k, kind=kind, loop=loop, T=T))
                if (i + 1) % 5 == 0 or i + 1 == len(states):
                    el = time.time() - t1
                    log(f"  {scenario}: state {i + 1}/{len(states)} (case {c}, step {k}, {kind}) {el:.0f} s, "
                        f"ETA {el / (i + 1) * (len(states) - i - 1):.0f} s")
            out["alpha"] = float(trainer.timing_taker.log_alpha.detach().exp())
            for pair in (LOOPS[:2], LOOPS[2:]):  # T = 1: beta = 1 with a fresh a_t in both semantics
                for b1, b2 in zip(*([b for b in out["branches"] if b["T"] == 1 and b["loop"] == lp] for lp in pair)):
                    assert (b1["outcome"], b1["ret"]) == (b2["outcome"], b2["ret"]), "T = 1: the two loops differ"
    finally:
        env.close()
    out["wall_s"] = round(time.time() - t0, 1)
    return out


# ---- The report: summary.md and ranking.png from every {scenario}.json ------------------------------


def ranks(x) -> np.ndarray:
    """Rank 1 = the largest value; ties share their mean rank."""
    x = np.asarray(x, dtype=float)
    order = np.argsort(-x, kind="stable")
    r = np.empty(len(x))
    r[order] = np.arange(1, len(x) + 1)
    for v in np.unique(x[np.isfinite(x)]):
        r[x == v] = r[x == v].mean()
    return r


def spearman(x, y) -> float:
    """Spearman's rank correlation: Pearson's correlation of the ranks."""
    rx, ry = ranks(x), ranks(y)
    return float(np.corrcoef(rx, ry)[0, 1]) if rx.std() and ry.std() else float("nan")


def aggregate(branches: list[dict], t_max: int, kind: str | None = None) -> dict:
    """Per loop, per T = 1..t_max: n, arrival / collision / timeout rates, mean return and discounted return,
    the standard error of the mean discounted return paired with TARL's own continuation from the same
    states (se), and the rank of T by mean discounted return. "original": TARL's own continuation (T = 0)."""
    own = {(b["case"], b["k"]): b["disc"] for b in branches if b["loop"] == "original"}
    out = {}
    for loop in ("original", *LOOPS):
        rows = []
        for T in [0] if loop == "original" else range(1, t_max + 1):
            sel = [b for b in branches if b["loop"] == loop and b["T"] == T and kind in (None, b["kind"])]
            mean = lambda v: float(np.mean(v)) if len(v) else float("nan")  # noqa: E731
            diff = [b["disc"] - own[b["case"], b["k"]] for b in sel]
            rows.append(dict(T=T, n=len(sel), **{o: mean([b["outcome"] == o for b in sel]) for o in OUTCOMES},
                             ret=mean([b["ret"] for b in sel]), disc=mean([b["disc"] for b in sel]),
                             se=float(np.std(diff) / np.sqrt(len(diff))) if diff else float("nan")))
        if loop != "original":
            for row, r in zip(rows, ranks([row["disc"] for row in rows])):
                row["rank"] = float(r)
        out[loop] = rows
    return out


def loop_table(agg: dict, loops, picks, title: str) -> list[str]:
    head = " | ".join(f"{lp}: arr / col / to | return; disc. +- se | rank" for lp in loops)
    rows = [f"| {T} | {picks[T - 1]:.2f} | " + " | ".join(
        f"{r['arrival']:.2f} / {r['collision']:.2f} / {r['timeout']:.2f} | {r['ret']:.2f}; {r['disc']:.2f} +- "
        f"{r['se']:.2f} | {r['rank']:g}" for r in (agg[lp][T - 1] for lp in loops)) + " |" for T in range(1, len(picks) + 1)]
    return [f"{title}:", "", f"| T | taker's pick | {head} |", "|---" * (2 + 3 * len(loops)) + "|", *rows]


def probed(res: dict) -> str:
    """The row whose policy a JSON probed: "TARL", or a variant's --algo (JSONs from before --algo are TARL's)."""
    return "TARL" if res.get("algo", "tarl") == "tarl" else res["algo"]


def markdown(results: list[dict]) -> str:
    lines = ["# The ranking of T in the timing imagination and in the real loop, from the same states", "",
             "Written by `python bench/timing_probe.py` (its docstring says what each loop is). Per T: the arrival / "
             "collision / timeout rates over the branches, the mean return from the branch point, the mean discounted "
             "return (gamma = 0.99) +- its standard error paired with the policy's own continuation from the same states, "
             "and the rank of T by mean discounted return (1 = best). Taker's pick: the share of states where T is "
             "the timing taker's most likely T (Sec. 5.3's deterministic choice).", ""]
    for res in results:
        n_t, states, agg = res["t_max"], res["states"], aggregate(res["branches"], res["t_max"])
        picks = np.bincount([s["taker_T"] for s in states], minlength=n_t + 1)[1:n_t + 1] / len(states)
        o, pi = agg["original"][0], np.mean([s["taker_pi"] for s in states], 0)[:n_t]
        who = probed(res)
        lines += [f"## {res['scenario']}" + ("" if who == "TARL" else f", {who}"), "",
                  f"{len(states)} states ({sum(s['kind'] == 'regular' for s in states)} every {res['every']} steps "
                  f"of {res['cases']} test cases, {sum(s['kind'] == 'crash' for s in states)} in the last 3 s "
                  f"before {len(res['crash_cases'])} collisions); {who}'s own continuation from them: arrival "
                  f"{o['arrival']:.2f}, collision {o['collision']:.2f}, timeout {o['timeout']:.2f}, return "
                  f"{o['ret']:.2f} (discounted {o['disc']:.2f}). Wall time {res['wall_s'] / 60:.1f} min.", "",
                  *loop_table(agg, LOOPS[:2], picks, f"One decision, then {who}'s driver"), "",
                  *loop_table(agg, LOOPS[2:], picks, "Constant T to the end")]
        rho = {kind: {lp: [r["disc"] for r in aggregate(res["branches"], n_t, kind)[lp]] for lp in LOOPS}
               for kind in (None, "regular", "crash")}
        rho = {pair: [spearman(d[pair[0]], d[pair[1]]) for d in rho.values()] for pair in (LOOPS[:2], LOOPS[2:])}
        spread = ", ".join(f"{lp} {np.ptp([r['disc'] for r in agg[lp]]):.2f} (median se "
                           f"{np.median([r['se'] for r in agg[lp]]):.2f})" for lp in LOOPS)
        lines += ["", "Spearman rank correlation of the two loops' rankings of T by mean discounted return (all "
                  "states; the regular ones; those before collisions): " + "; ".join(
                      f"{p[0]} vs {p[1]} **{r[0]:.2f}** ({r[1]:.2f}; {r[2]:.2f})" for p, r in rho.items()) +
                  f". The taker's mean pi(T) vs imagination {spearman(pi, [r['disc'] for r in agg['imagination']]):.2f}, "
                  f"vs real {spearman(pi, [r['disc'] for r in agg['real']]):.2f}. Range of the mean discounted return "
                  f"over T: {spread}.", ""]
        own = {(b["case"], b["k"]): b["outcome"] for b in res["branches"] if b["loop"] == "original"}
        changed = {lp: max(sum(b["outcome"] != own[b["case"], b["k"]] for b in res["branches"] if b["loop"] == lp
                               and b["T"] == T and b["kind"] == "regular") for T in range(1, n_t + 1)) for lp in LOOPS[:2]}
        lines += [f"From the regular states, one decision changed {who}'s outcome in at most {changed['imagination']} "
                  f"(imagination) and {changed['real']} (real) of them for any T.", ""]
        crash, sel = aggregate(res["branches"], n_t, "crash"), [s["taker_T"] for s in states if s["kind"] == "crash"]
        if sel:
            picks = np.bincount(sel, minlength=n_t + 1)[1:n_t + 1] / len(sel)
            lines += [f"The {len(sel)} states before collisions alone ({who}'s own continuation collides from each): "
                      "arrival / collision rate; mean discounted return.", "",
                      "| T | taker's pick | " + " | ".join(LOOPS) + " |", "|---" * (2 + len(LOOPS)) + "|"]
            lines += [f"| {T} | {picks[T - 1]:.2f} | " + " | ".join(
                f"{r['arrival']:.2f} / {r['collision']:.2f}; {r['disc']:.1f}" for r in (crash[lp][T - 1] for lp in LOOPS))
                + " |" for T in range(1, n_t + 1)]
            lines.append("")
        lines += critic_lines(res)
    return "\n".join(lines)


def critic_lines(res: dict) -> list[str]:
    """What the timing taker's critic predicts for each T, beside what each T led to from the same states: is its
    ranking of T the measured one, and is it too optimistic where T decides (before collisions)?"""
    if "taker_q" not in res["states"][0]:
        return []
    n_t, kinds = res["t_max"], ((None, "all states"), ("regular", "regular states"), ("crash", "before collisions"))
    disc = {(b["case"], b["k"], b["loop"], b["T"]): b["disc"] for b in res["branches"]}
    lines = [f"### The timing taker's critic, from the same states (alpha = {res.get('alpha', float('nan')):.3f})", "",
             "min(Q1, Q2)(s, a, T) of Eq. (9) at each state, beside the measured discounted return of one decision "
             "with T then the policy's driver (imagination: Eq. (7); real: beta(T)). Q's own continuation is more "
             "imagination decisions, so its level may differ; its ranking of T is what the taker acts on. "
             "Spearman: per state, Q(s, a, .) against the measured returns over T, the mean over states.", ""]
    for kind, title in kinds:
        states = [st for st in res["states"] if kind in (None, st["kind"])]
        if not states:
            continue
        q = np.array([st["taker_q"][:n_t] for st in states])
        m = {lp: np.array([[disc[st["case"], st["k"], lp, T] for T in range(1, n_t + 1)] for st in states])
             for lp in LOOPS[:2]}
        rho = {lp: np.nanmean([spearman(qi, mi) for qi, mi in zip(q, m[lp])]) for lp in m}
        own = np.mean([disc[st["case"], st["k"], "original", 0] for st in states])
        best = {lp: np.bincount(m[lp].argmax(1), minlength=n_t) / len(states) for lp in m}
        pick = np.bincount(q.argmax(1), minlength=n_t) / len(states)
        lines += [f"{title} ({len(states)}): Spearman Q vs imagination **{rho['imagination']:.2f}**, vs real "
                  f"**{rho['real']:.2f}**. The actor's critic min Q(s, a) (Eq. (13)) at the same states: "
                  f"{np.mean([st['actor_q'] for st in states]):.2f}, against the policy's own continuation's measured "
                  f"{own:.2f}.", "",
                  "| T | mean Q | measured, imagination | measured, real | argmax Q | best, imagination | best, real |",
                  "|---|---|---|---|---|---|---|"]
        lines += [f"| {T} | {q[:, T - 1].mean():.2f} | {m['imagination'][:, T - 1].mean():.2f} | "
                  f"{m['real'][:, T - 1].mean():.2f} | {pick[T - 1]:.2f} | {best['imagination'][T - 1]:.2f} | "
                  f"{best['real'][T - 1]:.2f} |" for T in range(1, n_t + 1)]
        lines.append("")
    return lines


STYLE = {"imagination": ("C0", "-", "o", "imagination: one Eq. (7) decision, then TARL"),
         "real": ("C1", "-", "s", "real loop: beta(T) for T steps, then TARL"),
         "imagination-const": ("C0", "--", "^", "imagination: Eq. (7) decisions to the end"),
         "real-const": ("C1", "--", "v", "real loop: beta(T) to the end")}


def figure(results: list[dict], path: Path):
    """Per scenario (columns), against T: the arrival rate from all states and from those before collisions,
    the mean discounted return (+- se) of the one-decision and of the constant-T branches; TARL's own dotted."""
    import matplotlib.pyplot as plt  # noqa: PLC0415 (the Agg backend: no display)
    fig, axes = plt.subplots(4, len(results), figsize=(5.5 * len(results), 13), squeeze=False)
    panels = (("arrival", None, "arrival rate, all states", LOOPS), ("arrival", "crash", "arrival rate, last 3 s "
              "before a collision", LOOPS), ("disc", None, "mean discounted return", LOOPS[:2]),
              ("disc", None, "mean discounted return", LOOPS[2:]))
    for col, res in enumerate(results):
        Ts, who = np.arange(1, res["t_max"] + 1), res["scenario"] + ("" if probed(res) == "TARL" else f", {probed(res)}")
        for row, (key, kind, label, loops) in enumerate(panels):
            ax, agg = axes[row, col], aggregate(res["branches"], res["t_max"], kind)
            for lp in loops:
                c, ls, m, name = STYLE[lp]
                y, se = np.array([r[key] for r in agg[lp]]), np.array([r["se"] for r in agg[lp]])
                ax.plot(Ts, y, color=c, ls=ls, marker=m, ms=5, label=name)
                if key == "disc":
                    ax.fill_between(Ts, y - se, y + se, color=c, alpha=0.15, lw=0)
            ax.axhline(agg["original"][0][key], color="grey", ls=":", label="the policy's own continuation")
            ax.set(xlabel="T [steps]", ylabel=label, xticks=Ts, title=f"{who}: {agg['original'][0]['n']} states")
            ax.grid(alpha=0.3)
    fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="upper center", ncol=3, fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.955))
    fig.savefig(path, dpi=100)
    plt.close(fig)


def report(out: Path = OUT, log=print):
    results = [json.loads(p.read_text()) for s in sorted(world.SCENARIOS) for p in sorted(out.glob(f"{s}*.json"))]
    if not results:
        raise SystemExit(f"no results in {out}: run the probe first")
    (out / "summary.md").write_text(markdown(results))
    figure(results, out / "ranking.png")
    log(f"wrote {out / 'summary.md'} and {out / 'ranking.png'}")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--scenario", choices=(*sorted(world.SCENARIOS), "both"), default="both")
    p.add_argument("--cases", type=int, default=8, help="test cases of round 0 whose states are branched from")
    p.add_argument("--every", type=int, default=20, help="[steps] between the branch states of a case")
    p.add_argument("--crash-search", type=int, default=200, help="test cases of round 0 searched for collisions")
    p.add_argument("--crash-cases", type=int, default=4, help="at most this many collisions' last 3 s are branched from")
    p.add_argument("--crash-every", type=int, default=5, help="[steps] between the branch states before a collision")
    p.add_argument("--algo", default="tarl", choices=[a for a, row in experiment.ROWS.items() if row.timing == "taker"],
                   help="the row whose shipped seed-0 policy (results/runs/SCENARIO-ALGO-s0/policy.pt) is probed; "
                        "its JSON is SCENARIO.json for TARL, SCENARIO-ALGO.json for another")
    p.add_argument("--out", type=Path, default=OUT)
    p.add_argument("--report", action="store_true", help="only rewrite summary.md and ranking.png from the JSONs")
    p.add_argument("--critic", type=Path, metavar="CKPT", help="add the timing taker's Q(s, a, T) of this ckpt.pt of "
                   "the shipped run (a retrain: training is deterministic) to the states of the --scenario's JSON "
                   "(no branch is played; the same policies and states, checked), then the report")
    args = p.parse_args(argv)
    torch.set_num_threads(1)  # beside other busy processes
    args.out.mkdir(parents=True, exist_ok=True)
    if args.critic and args.scenario == "both":
        p.error("--critic CKPT is one scenario's run: give --scenario")
    name = lambda sc: f"{sc}.json" if args.algo == "tarl" else f"{sc}-{args.algo}.json"  # noqa: E731
    if args.critic:
        sc = args.scenario
        if not (args.out / name(sc)).exists():
            p.error(f"--critic adds to {args.out / name(sc)}: run the probe of --scenario {sc} --algo {args.algo} first")
        old = json.loads((args.out / name(sc)).read_text())
        new = probe(sc, old["cases"], old["every"], args.crash_search, len(old["crash_cases"]), args.crash_every,
                    critic=args.critic, algo=args.algo)
        assert [(s["case"], s["k"], s["taker_pi"]) for s in new["states"]] == \
               [(s["case"], s["k"], s["taker_pi"]) for s in old["states"]], f"{sc}: not the JSON's states"
        old.update(states=new["states"], alpha=new["alpha"])
        (args.out / name(sc)).write_text(json.dumps(old))
    if not args.report and not args.critic:
        for sc in sorted(world.SCENARIOS) if args.scenario == "both" else [args.scenario]:
            res = probe(sc, args.cases, args.every, args.crash_search, args.crash_cases, args.crash_every, algo=args.algo)
            (args.out / name(sc)).write_text(json.dumps(res))
            print(f"{sc}: {len(res['branches'])} branches in {res['wall_s'] / 60:.1f} min -> {args.out / name(sc)}")
    report(args.out)


if __name__ == "__main__":
    main()
