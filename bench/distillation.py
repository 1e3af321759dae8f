"""Distilling the rollout timing (distil.py): the teacher's labels on training traffic, three students, their curve.

    python bench/distillation.py label --scenario roundabout --cases 1000 --commit   # resumable, a chunk per commit
    python bench/distillation.py train --scenario roundabout                         # students A, B, C and the curve

label: TARL's committed actor (results/runs/SCENARIO-tarl-sSEED/policy.pt, --actor-seed) crosses cases recorded from
seeds of their own, never a test seed (label_seed), timed by the rollout teacher (distil.Teacher, the rollout timing's
defaults). Each chunk of --chunk cases is one compressed file, results/distil/labels/SCENARIO-sSEED/chunkK.npz, with
every decision's features, action, each candidate's return in each future and the teacher's T, and each case's
outcome; an interrupted run loses at most the chunk it was playing.

train: chunks K % 5 == 4 are held out (cases, never decisions, are split). Each student is fitted on the others; the
held-out agreement with the teacher and regret (distil.regret: the return lost against the best candidate, mean
per decision) are written to results/distil/SCENARIO-sSEED/students.md with the regret of T = 2 always, and the
curve of regret against the number of training cases. The students go beside it as A.pt, B.pt, C.pt, for
`tarl.py --load ... --timing distilled=PATH`.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
import tarl  # noqa: E402, I001 (first: it sets OpenMP's wait policy before torch loads)
import distil  # noqa: E402
import experiment  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from rollout_timing import RolloutConfig  # noqa: E402
from timing_probe import load_tarl  # noqa: E402

OUT = ROOT / "results" / "distil"
SCENARIOS = ("intersection", "roundabout")
LABEL_SEED = 500_000  # chunk K's cases come from SUMO and traffic seed LABEL_SEED + K
HELD_OUT = 5  # chunks K % HELD_OUT == HELD_OUT - 1 are held out
CURVE = (0.125, 0.25, 0.5, 1.0)  # shares of the training chunks on the curve


def label_seed(chunk: int) -> int:
    """The seed of a chunk's cases: below every test seed (experiment.test_seed(s, r) >= test_seed(0, 0) for all s,
    r >= 0), and not a training seed (tarl.py --seed is small; later restarts draw from the traffic's own rng)."""
    seed = LABEL_SEED + chunk
    if not 0 <= chunk < experiment.test_seed(0, 0) - LABEL_SEED:
        raise ValueError(f"chunk {chunk}: label seeds run from {LABEL_SEED} up to the first test seed")
    return seed


def policy_path(scenario: str, actor_seed: int) -> Path:
    return ROOT / "results" / "runs" / f"{scenario}-tarl-s{actor_seed}" / "policy.pt"


def folder(scenario: str, actor_seed: int, out: Path = OUT) -> Path:
    return out / "labels" / f"{scenario}-s{actor_seed}"


def meta(scenario: str, actor_seed: int, chunk: int, cases: int) -> dict:
    """What a chunk was labelled with (as JSON keeps it): a chunk with other meta is not resumed."""
    return json.loads(json.dumps(dict(scenario=scenario, actor_seed=actor_seed, chunk=chunk, cases=cases, seed=label_seed(chunk),
                actor=hashlib.sha1(policy_path(scenario, actor_seed).read_bytes()).hexdigest()[:16],
                rollout=asdict(RolloutConfig()), world=experiment.world.WORLD_VERSION)))


def read_chunk(path: Path) -> tuple[dict, dict]:
    with np.load(path) as z:
        return json.loads(str(z["meta"])), {k: z[k] for k in z.files if k != "meta"}


def label_chunk(env, teacher, scenario: str, actor_seed: int, chunk: int, cases: int, log=print) -> dict:
    """One chunk's labels: its cases recorded, each crossed by the actor timed by the teacher."""
    decisions, per_case, t0 = [], [], time.time()
    with tempfile.TemporaryDirectory() as tmp:
        for c, case in enumerate(env.record_cases(label_seed(chunk), cases, tmp)):
            ep = experiment.rollout(env, teacher, {"case": case})
            decisions += [dict(d, case=c) for d in teacher.labels]
            per_case.append((ep["outcome"], ep["steps"], ep["decisions"], ep["branch_steps"], ep["wall_s"]))
            done = time.time() - t0
            log(f"  chunk {chunk}, case {c + 1}/{cases}: {ep['outcome']}, {ep['decisions']} decisions, {ep['wall_s']:.0f} s"
                f" [ETA of the chunk {done / (c + 1) * (cases - c - 1):.0f} s]")
    arrays = {k: np.stack([d[k] for d in decisions]) for k in decisions[0]} if decisions else {}
    outcome, steps, n_dec, branch, wall = zip(*per_case)
    return dict(arrays, outcome=np.array(outcome), steps=np.array(steps), decisions=np.array(n_dec),
                branch_steps=np.array(branch), wall_s=np.array(wall))


def label(args):
    path = policy_path(args.scenario, args.actor_seed)
    if not path.exists():
        raise SystemExit(f"no committed TARL policy {path.relative_to(ROOT)}: train it first (bench/table3.py)")
    keep = folder(args.scenario, args.actor_seed, args.out)
    keep.mkdir(parents=True, exist_ok=True)
    todo = []
    for k in range(-(-args.cases // args.chunk)):
        file, want = keep / f"chunk{k:03d}.npz", meta(args.scenario, args.actor_seed, k, args.chunk)
        if file.exists():
            if {k: v for k, v in read_chunk(file)[0].items() if k in want} != want:
                raise SystemExit(f"{file} was labelled with other settings; move it away to relabel")
            continue
        todo.append((k, file, want))
    print(f"labels on the {args.scenario}, actor seed {args.actor_seed}: {len(todo)} of {-(-args.cases // args.chunk)} "
          f"chunks of {args.chunk} cases to play -> {keep}", flush=True)
    if not todo:
        return
    env = tarl.DrivingEnv(tarl.EnvConfig(scenario=args.scenario))
    trainer = load_tarl(env, args.scenario, path)
    teacher = distil.Teacher(trainer.actor, 0, trainer.tc.timing, RolloutConfig())
    t0 = time.time()
    try:
        for n, (k, file, want) in enumerate(todo, 1):
            arrays = label_chunk(env, teacher, args.scenario, args.actor_seed, k, args.chunk,
                                 log=lambda s: print(s, flush=True))
            want.update(machine=experiment.machine(), minutes=round((time.time() - t0) / 60 / n, 2))
            part = file.with_suffix(".part.npz")
            np.savez_compressed(part, meta=json.dumps(want), **arrays)
            part.rename(file)  # whole or absent: an interrupted write leaves no chunk
            print(f"chunk {k} done: {len(arrays.get('T', []))} decisions [{n}/{len(todo)} chunks, "
                  f"{(time.time() - t0) / 60:.0f} min, ETA {(time.time() - t0) / n * (len(todo) - n) / 60:.0f} min]",
                  flush=True)
            if args.commit:
                from table3 import commit  # bench/table3.py's: add and commit just these files
                commit([file], f"distil labels: {args.scenario}, actor seed {args.actor_seed}, chunk {k}")
    finally:
        env.close()


def load_labels(scenario: str, actor_seed: int, out: Path = OUT) -> tuple[dict, list[int]]:
    """Every labelled decision of a scenario and actor, its chunk beside it; and the chunks found."""
    files = sorted(folder(scenario, actor_seed, out).glob("chunk[0-9][0-9][0-9].npz"))
    if not files:
        raise SystemExit(f"no labels in {folder(scenario, actor_seed, out)}: run `label` first")
    parts, chunks = [], []
    for f in files:
        m, a = read_chunk(f)
        if "T" in a:
            parts.append(dict({k: a[k] for k in (*distil.GROUPS, "returns", "T", "case")},
                              chunk=np.full(len(a["T"]), m["chunk"])))
        chunks.append(m["chunk"])
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}, chunks


def train(args):
    data, chunks = load_labels(args.scenario, args.actor_seed, args.out)
    cfg = RolloutConfig()
    held = data["chunk"] % HELD_OUT == HELD_OUT - 1
    if not held.any() or held.all():
        raise SystemExit(f"{len(chunks)} chunks: at least {HELD_OUT} are needed, one of them held out")
    train_chunks = sorted({int(c) for c in data["chunk"][~held]})
    adv = distil.advantages(data["returns"], cfg)
    test = {k: v[held] for k, v in data.items()}
    out = args.out / f"{args.scenario}-s{args.actor_seed}"
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)

    def scores(chosen):
        return dict(agreement=float(np.mean(chosen == test["T"])), regret=float(distil.regret(test["returns"], chosen,
                                                                                              cfg).mean()))

    results, curve = {}, {}
    for inputs in args.students:
        for share in CURVE:
            use = np.isin(data["chunk"], train_chunks[:max(1, round(share * len(train_chunks)))]) & ~held
            student = distil.fit(distil.design(data, inputs)[use], adv[use], inputs, cfg)
            curve.setdefault(inputs, []).append(dict(cases=int(len({(c, k) for c, k in zip(data["chunk"][use],
                                                                                             data["case"][use])})),
                                                     decisions=int(use.sum()),
                                                     **scores(student.choose(distil.design(test, inputs)))))
        student.save(out / f"{inputs}.pt")
        results[inputs] = curve[inputs][-1]
        print(f"student {inputs}: {results[inputs]}", flush=True)
    baseline = {"T = 2 always": scores(np.full(held.sum(), cfg.default_T)),
                "the teacher's most frequent T": scores(np.full(held.sum(), np.bincount(data["T"][~held]).argmax()))}
    (out / "students.json").write_text(json.dumps(dict(results=results, curve=curve, baseline=baseline,
                                                       train_chunks=train_chunks, held_out_decisions=int(held.sum()),
                                                       train_decisions=int((~held).sum())), indent=1))
    print(json.dumps(baseline))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    for name in ("label", "train"):
        s = sub.add_parser(name)
        s.add_argument("--scenario", choices=SCENARIOS, required=True)
        s.add_argument("--actor-seed", type=int, default=0, help="whose committed TARL actor (results/runs)")
        s.add_argument("--out", type=Path, default=OUT, help="where the labels and students go")
    lab = sub.choices["label"]
    lab.add_argument("--cases", type=int, default=1000, help="cases to label, in chunks")
    lab.add_argument("--chunk", type=int, default=20, help="cases per chunk (one file, one commit)")
    lab.add_argument("--commit", action="store_true", help="git commit each chunk as it finishes")
    sub.choices["train"].add_argument("--students", nargs="+", default=list(distil.INPUTS),
                                      help="input sets: A, B, C, or one less a group (C-routes)")
    args = p.parse_args(argv)
    if args.command == "label":
        if args.cases < 1 or args.chunk < 1:
            p.error("--cases and --chunk are at least 1")
        torch.set_num_threads(1)
        label(args)
    else:
        for inputs in args.students:
            try:
                distil.groups(inputs)
            except ValueError as e:
                p.error(str(e))
        train(args)


if __name__ == "__main__":
    main()
