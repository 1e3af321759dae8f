"""The ceiling of a state-dependent timing: TARL's seed-0 actor timed by simulated branches (beyond/rollout_timing.py),
paired case by case with the fixed T = 2, the random T and the learned timing of the same actor.

    python bench/rollout_ceiling.py --commit                     # play or resume both scenarios, round by round
    python bench/rollout_ceiling.py --scenarios roundabout --commit   # one scenario (a process per core)
    python bench/rollout_ceiling.py --timing rollout=2 --commit  # the control: the same saves and reloads, T = 2
    python bench/rollout_ceiling.py --report                     # results/rollout/summary.md from what is there

The actor is the shipped results/runs/SCENARIO-tarl-s0/policy.pt; the cases are rounds 0..R-1 of seed 0's test
cases, the same as every row of Table 3. Each finished round is kept in results/rollout/SCENARIO-TIMING/roundR.json
(committed with --commit), so an interrupted run loses at most the round it was playing. The other timings'
outcomes are the committed ones: TARL's eval.json (learned) and results/retime/ (fixed=2, random, fixed=3).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
import tarl  # noqa: E402, F401, I001 (first: it sets OpenMP's wait policy before torch loads)
import experiment  # noqa: E402
import numpy as np  # noqa: E402
from beyond import rollout_timing  # noqa: E402
import torch  # noqa: E402
from analysis.compare import read_row  # noqa: E402
from analysis.paired import p_text, paired  # noqa: E402
from timing_probe import load_tarl  # noqa: E402
import world  # noqa: E402

OUT = ROOT / "results" / "rollout"
SCENARIOS = ("intersection", "roundabout")
ABLATIONS = ("fixed=2", "random")  # the timings a learned one must beat (Table 3's ablations, re-timed on this actor)
OTHERS = ("learned", *ABLATIONS, "fixed=3")
MARGIN = 0.01  # success the rollout timing must gain over the better ablation, with McNemar p < ALPHA, to go on
ALPHA = 0.05


def tag(timing: str) -> str:
    return timing.replace("=", "").replace(",", "-")


def other_row(scenario: str, timing: str) -> dict:
    """TARL's seed-0 actor under a committed timing: its row of eval.json (the learned timing's) or of results/retime."""
    run = experiment.run_name(scenario, "tarl", 0)
    return read_row(ROOT / "results" / "runs" / run / "eval.json" if timing == "learned"
                    else ROOT / "results" / "retime" / f"{run}-{tag(timing)}.json", "tarl")


def play(scenario: str, timing: str, rounds: int, cases: int, workers: int, commit: bool, out: Path = OUT):
    """Rounds 0..rounds-1 with the rollout timing, one at a time, each kept (and committed) as it finishes: in
    `workers` processes, or with none in this one, on the env that loaded the policy."""
    env = world.DrivingEnv(world.EnvConfig(scenario=scenario))
    trainer = load_tarl(env, scenario)  # the shipped seed-0 policy
    if workers:  # the env is needed here only to play the rounds in this process
        env.close()
    rows = [dict(algo="tarl", label=f"TARL, T {timing}", driver=experiment.timing_override(timing, trainer))]
    keep = out / f"{scenario}-{tag(timing)}"
    for r in range(rounds):
        if experiment.kept_round(keep, r, experiment.evaluation_key(env.cfg, rows, cases, 0)) is not None:
            continue
        print(f"{scenario}, {timing}: round {r + 1}/{rounds}", flush=True)
        experiment.evaluate(env.cfg, rows, r + 1, cases, 0, workers, env, keep=keep)
        if commit:
            from table3 import commit as git_commit  # bench/table3.py's: add and commit just these files
            git_commit([keep / f"round{r}.json"], f"rollout ceiling: TARL seed 0 on the {scenario}, --timing {timing}, "
                       f"round {r}")
    # every round is kept by now: this gathers them (quietly: nothing was interrupted)
    result = experiment.evaluate(env.cfg, rows, rounds, cases, 0, workers, env, log=lambda line: None, keep=keep)[0]
    env.close()
    path = out / f"{experiment.run_name(scenario, 'tarl', 0)}-{tag(timing)}.json"
    path.write_text(json.dumps(dict(scenario=scenario, seed=0, world=experiment.world.WORLD_VERSION,
                                    machine=experiment.machine(), rows=[result])))
    return path


def report(out: Path = OUT, timings=("rollout", "rollout=2")) -> str:
    rng, lines = np.random.default_rng(0), ["# The ceiling of a state-dependent timing", "",
                                            "Built by `python bench/rollout_ceiling.py --report` from the rounds in "
                                            "results/rollout/ (module docstring of beyond/rollout_timing.py: how it chooses).", ""]
    for scenario in SCENARIOS:
        for timing in timings:
            keep = out / f"{scenario}-{tag(timing)}"
            rounds = sorted(keep.glob("round*.json"), key=lambda p: int(p.stem[5:]))
            if not rounds:
                continue
            eps = [ep for p in rounds for ep in json.loads(p.read_text())["rows"][0]]
            mine = dict(cases=eps)
            n = len(eps)
            rate = {o: np.mean([ep["outcome"] == o for ep in eps]) for o in ("arrival", "collision", "timeout")}
            steps, branch = np.mean([ep["steps"] for ep in eps]), np.mean([ep["branch_steps"] for ep in eps])
            lines += [f"## {scenario}, --timing {timing}", "",
                      f"{n} cases (rounds {', '.join(p.stem[5:] for p in rounds)} of seed 0): success {rate['arrival']:.3f}, "
                      f"collision {rate['collision']:.3f}, timeout {rate['timeout']:.3f}. Per case: "
                      f"{np.mean([ep['decisions'] for ep in eps]):.1f} decisions, {steps:.0f} steps, {branch:.0f} branch "
                      f"steps ({(steps + branch) / steps:.0f} x the simulator steps of a plain episode), "
                      f"{np.mean([ep['wall_s'] for ep in eps]):.1f} s wall time.", "",
                      "| against | its success | rollout only / it only arrives | McNemar p | rollout - it [95 % CI, cases resampled in each round] |",
                      "|---|---|---|---|---|"]
            res = {o: paired(mine, other_row(scenario, o), rng) for o in OTHERS}
            lines += [f"| {o} | {r['other']:.3f} | {r['only_mine']} / {r['only_other']} | {p_text(r['p'])} | "
                      f"{r['diff']:+.3f} [{r['low']:+.3f}, {r['high']:+.3f}] |" for o, r in res.items()]
            best = max(ABLATIONS, key=lambda o: res[o]["other"])
            r = res[best]
            verdict = "beats" if r["diff"] >= MARGIN and r["p"] < ALPHA else "does not beat"
            lines += ["", f"Against the better ablation on these cases ({best}): the rollout timing **{verdict}** it by "
                      f"{MARGIN} with p < {ALPHA} ({r['diff']:+.3f}, p {p_text(r['p'])}).", ""]
    return "\n".join(lines) + "\n"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenarios", nargs="+", choices=SCENARIOS, default=list(SCENARIOS))
    p.add_argument("--timing", default="rollout", help="rollout or rollout=T1,T2,... (beyond/rollout_timing.py)")
    p.add_argument("--rounds", type=int, default=2, help="rounds 0..R-1 of seed 0's test cases")
    p.add_argument("--cases", type=int, default=200, help="cases per round (Table 3: 200)")
    p.add_argument("--workers", type=int, default=1, help="evaluation processes (each plays a round); 0: in this one")
    p.add_argument("--commit", action="store_true", help="git commit each finished round and the summary")
    p.add_argument("--report", action="store_true", help="only rewrite OUT/summary.md")
    p.add_argument("--out", type=Path, default=OUT, help="where the rounds, each scenario's eval.json and summary.md go")
    args = p.parse_args(argv)
    try:
        rollout_timing.parse(args.timing) or p.error(f"--timing {args.timing}: rollout or rollout=T1,T2,...")
    except ValueError as e:
        p.error(str(e))
    if not 1 <= args.rounds <= 10 or not 1 <= args.cases <= 200:
        p.error("--rounds is 1..10 and --cases 1..200: the other timings' outcomes are on Table 3's 10 x 200 cases")
    torch.set_num_threads(1)
    args.out.mkdir(parents=True, exist_ok=True)
    if not args.report:
        t0 = time.time()
        for scenario in args.scenarios:
            path = play(scenario, args.timing, args.rounds, args.cases, args.workers, args.commit, args.out)
            print(f"wrote {path} ({(time.time() - t0) / 60:.1f} min)", flush=True)
    (args.out / "summary.md").write_text(report(args.out))
    print((args.out / "summary.md").read_text())
    if args.commit and not args.report:
        from table3 import commit as git_commit
        git_commit([args.out], f"rollout ceiling: {args.timing} on the {', '.join(args.scenarios)}, summary")


if __name__ == "__main__":
    main()
