"""Distilling the rollout timing (beyond/distil.py): the teacher's labels on training traffic, three students, their curve.

    python bench/distillation.py label --scenario roundabout --cases 1000 --commit   # resumable, a chunk per commit
    python bench/distillation.py train --scenario roundabout                         # students A, B, C and the curve
    python bench/distillation.py evaluate --scenario roundabout --commit             # each student through the gate
    python bench/distillation.py report                                              # results/distil/summary.md

label: TARL's committed actor (results/runs/SCENARIO-tarl-sSEED/policy.pt, --actor-seed) crosses cases recorded from
seeds of their own, never a test seed (label_seed), timed by the rollout teacher (distil.Teacher, the rollout timing's
defaults). Each chunk of --chunk cases is one compressed file, results/distil/labels/SCENARIO-sSEED/chunkK.npz, with
every decision's features, action, each candidate's return in each future and the teacher's T, and each case's
outcome; an interrupted run loses at most the chunk it was playing.

train: chunks K % 5 == 4 are held out (cases, never decisions, are split), and every 4th training chunk validates.
--loss decision (the default): each student is trained for the choice it makes (distil.fit_decision) on the other
training chunks, stopped early on the validation chunks; its students go to results/distil/SCENARIO-sSEED-decision.
--loss mse, the committed students of results/distil/SCENARIO-sSEED: fitted to every candidate's advantage on all
training chunks, a margin chosen on the validation chunks (choose_margin). The held-out agreement with the teacher
and regret (distil.regret: the return lost against the best candidate, mean per decision), overall and on the
decisive decisions, the gate (distil.gate) and the curve of regret against the number of training cases go to
students.json with those of T = 2 always. The students go beside it as A.pt, B.pt, C.pt, for `tarl.py --load ...
--timing distilled=PATH`.

evaluate: each student that passes the gate (held-out regret below T = 2 always, the case-bootstrap 95 % interval of
the difference excluding 0; --ungated: every student) times the same actor on the seed's 10 x 200 test cases
(`tarl.py --load ... --timing distilled=...`, resumable), its eval.json kept as eval-STUDENT.json beside it.

DAgger (one round): the student of A and B with the lower held-out regret (lower_regret) drives new cases while the
teacher labels its decisions (`label --student results/distil/roundabout-s0-decision --first-chunk 50 --cases 300`:
a folder's such student, or a student file; into labels/...-dagger-decision-B, -dagger-B for an mse student), then
`train --dagger B` fits every student on both sets and `evaluate --dagger B` plays them (in
SCENARIO-sSEED[-decision]-dagger). After it, the same rule in that folder names the student of record.

report: first the test registered on 2026-12-07 for the decision students' DAgger round (REGISTERED,
registered_test: the students of record at the intersection, pooled over seeds 0, 3 and 4); then the teacher's
labels measured (distil.reliability, distil.replicated_gain), every student's gate on its held-out decisions, then
every evaluated mse student's verdict: the rule registered before any student was evaluated
(docs/RESULTS.md, "What the timing adds"): a student passes if it beats the better of the trained ablation rows
tarl-fixed-t and tarl-random-t of the seed (the one with more successes on these cases) on the roundabout, McNemar
p < 0.05 on the 2,000 cases. Beside it, each student against TARL, TARL's actor re-timed with T = 2 and a random T
(results/retime) and the teacher on its 400 cases (results/rollout).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import re
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
import tarl  # noqa: E402, F401, I001 (first: it sets OpenMP's wait policy before torch loads)
from beyond import distil  # noqa: E402
import experiment  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from beyond.rollout_timing import RolloutConfig  # noqa: E402
from timing_probe import load_tarl  # noqa: E402
import world  # noqa: E402

OUT = ROOT / "results" / "distil"
SCENARIOS = ("intersection", "roundabout")
LABEL_SEED = 500_000  # chunk K's cases come from SUMO and traffic seed LABEL_SEED + K
HELD_OUT = 5  # chunks K % HELD_OUT == HELD_OUT - 1 are held out
CURVE = (0.125, 0.25, 0.5, 1.0)  # shares of the training chunks on the curve
MARGINS = (0.0, 0.5, 1.0, 2.0, 5.0, 10.0)  # [return] the margins tried for a student of loss mse (distil.Student)
VALIDATION = 4  # every 4th training chunk validates: the early stop, or an mse student's margin
DECISIVE = 5.0  # [return] a decision is decisive where some candidate beats T = 2 by this much (an outcome at stake)
LOSSES = ("decision", "mse")  # distil.Student.LOSSES, the default first


def label_seed(chunk: int) -> int:
    """The seed of a chunk's cases: below every test seed (experiment.test_seed(s, r) >= test_seed(0, 0) for all s,
    r >= 0), and not a training seed (tarl.py --seed is small; later restarts draw from the traffic's own rng)."""
    seed = LABEL_SEED + chunk
    if not 0 <= chunk < experiment.test_seed(0, 0) - LABEL_SEED:
        raise ValueError(f"chunk {chunk}: label seeds run from {LABEL_SEED} up to the first test seed")
    return seed


def policy_path(scenario: str, actor_seed: int) -> Path:
    return ROOT / "results" / "runs" / experiment.run_name(scenario, "tarl", actor_seed) / "policy.pt"


def folder(scenario: str, actor_seed: int, out: Path = OUT, student: str | None = None) -> Path:
    """Where a scenario's and actor's labels go: the teacher's own episodes, or (DAgger) those a student drove."""
    return out / "labels" / (f"{scenario}-s{actor_seed}" + (f"-dagger-{student}" if student else ""))


def students_dir(out: Path, scenario: str, actor_seed: int, dagger: bool, loss: str = "mse") -> Path:
    """Where a scenario's students, their scores and evaluations go: those of loss decision apart from the committed
    mse ones (SCENARIO-sSEED), those trained with DAgger labels apart (-dagger)."""
    return out / (f"{scenario}-s{actor_seed}" + f"-{loss}" * (loss != "mse") + "-dagger" * bool(dagger))


def lower_regret(students: Path) -> str:
    """Of a folder's students A and B, the one with the lower held-out regret (its students.json): before DAgger the
    student that drives the round, after it the student of record."""
    results = json.loads((students / "students.json").read_text())["results"]
    return min(("A", "B"), key=lambda name: results[name]["regret"])


def meta(scenario: str, actor_seed: int, chunk: int, cases: int, student: distil.Student | None = None) -> dict:
    """What a chunk was labelled with (as JSON keeps it): a chunk with other meta is not resumed."""
    m = dict(scenario=scenario, actor_seed=actor_seed, chunk=chunk, cases=cases, seed=label_seed(chunk),
             actor=hashlib.sha1(policy_path(scenario, actor_seed).read_bytes()).hexdigest()[:16],
             rollout=asdict(RolloutConfig()), world=experiment.world.WORLD_VERSION)
    return json.loads(json.dumps(m if student is None else dict(m, student=student.name, student_key=student.key())))


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
    if args.student is not None and args.student.is_dir():  # a folder of students: its lower_regret of A and B
        args.student = args.student / f"{lower_regret(args.student)}.pt"
    student = distil.Student.load(args.student) if args.student else None
    keep = folder(args.scenario, args.actor_seed, args.out, student and student.name)
    keep.mkdir(parents=True, exist_ok=True)
    todo = []
    for k in range(args.first_chunk, args.first_chunk + -(-args.cases // args.chunk)):
        file, want = keep / f"chunk{k:03d}.npz", meta(args.scenario, args.actor_seed, k, args.chunk, student)
        if file.exists():
            if {key: value for key, value in read_chunk(file)[0].items() if key in want} != want:
                raise SystemExit(f"{file} was labelled with other settings; move it away to relabel")
            continue
        todo.append((k, file, want))
    print(f"labels on the {args.scenario}, actor seed {args.actor_seed}: {len(todo)} of {-(-args.cases // args.chunk)} "
          f"chunks of {args.chunk} cases to play -> {keep}", flush=True)
    if not todo:
        return
    env = world.DrivingEnv(world.EnvConfig(scenario=args.scenario))
    trainer = load_tarl(env, args.scenario, path)
    teacher = distil.Teacher(trainer.actor, 0, trainer.tc.timing, RolloutConfig(), student)
    t0 = time.time()
    try:
        for n, (k, file, want) in enumerate(todo, 1):
            if file.exists():  # another labelling process of the same cases did it meanwhile
                continue
            started = time.time()
            arrays = label_chunk(env, teacher, args.scenario, args.actor_seed, k, args.chunk,
                                 log=lambda s: print(s, flush=True))
            want.update(machine=experiment.machine(), minutes=round((time.time() - started) / 60, 2))  # this chunk's
            part = file.with_suffix(".part.npz")
            np.savez_compressed(part, meta=json.dumps(want), **arrays)
            part.rename(file)  # whole or absent: an interrupted write leaves no chunk
            print(f"chunk {k} done: {len(arrays.get('T', []))} decisions [{n}/{len(todo)} chunks, "
                  f"{(time.time() - t0) / 60:.0f} min, ETA {(time.time() - t0) / n * (len(todo) - n) / 60:.0f} min]",
                  flush=True)
            if args.commit:
                from table3 import commit  # bench/table3.py's: add and commit just these files
                commit([file], f"distil labels: {args.scenario}, actor seed {args.actor_seed}, chunk {k}"
                                     + (f" (DAgger: student {student.name} drives)" if student else ""))
    finally:
        env.close()


def load_labels(scenario: str, actor_seed: int, out: Path = OUT, daggers=()) -> tuple[dict, list[int]]:
    """Every labelled decision of a scenario and actor (and of the DAgger rounds of these students, by name: B,
    decision-B), its chunk beside it; and the chunks found."""
    return read_labels([folder(scenario, actor_seed, out, d) for d in (None, *daggers)])


def read_labels(folders: list[Path], cache: dict | None = None) -> tuple[dict, list[int]]:
    """Every labelled decision in these label folders, its chunk beside it; and the chunks found. cache: a dict that
    keeps each folder's files read, for the next call."""
    if cache is not None:  # each folder read once, then joined
        for d in folders:
            if d not in cache and any(d.glob("chunk*.npz")):
                cache[d] = read_labels([d])
        read = [cache[d] for d in folders if d in cache]
        if not read:
            raise SystemExit(f"no labels in {', '.join(map(str, folders))}: run `label` first")
        return {k: np.concatenate([r[0][k] for r in read]) for k in read[0][0]}, [c for r in read for c in r[1]]
    files = sorted(f for d in folders for f in d.glob("chunk*.npz") if re.fullmatch(r"chunk\d+\.npz", f.name))
    if not files:
        raise SystemExit(f"no labels in {', '.join(map(str, folders))}: run `label` first")
    parts, chunks = [], []
    for f in files:
        m, a = read_chunk(f)
        if "T" in a:
            parts.append(dict({k: a[k] for k in (*distil.GROUPS, "returns", "T", "case")},
                              chunk=np.full(len(a["T"]), m["chunk"])))
        chunks.append(m["chunk"])
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}, chunks


def held_out(data: dict) -> np.ndarray:
    """Per decision, whether its chunk is held out (K % HELD_OUT == HELD_OUT - 1)."""
    return data["chunk"] % HELD_OUT == HELD_OUT - 1


def case_ids(data: dict) -> np.ndarray:
    """Per decision, its case's id (chunk and case in it): what a case bootstrap resamples."""
    return data["chunk"].astype(np.int64) * 10_000 + data["case"]


def validation_chunks(train_chunks: list[int]) -> list[int]:
    """Every VALIDATION-th training chunk (the last, if fewer): the early stop's, or an mse student's margin's."""
    return train_chunks[VALIDATION - 1::VALIDATION] or train_chunks[-1:]


def choose_margin(data: dict, adv: np.ndarray, inputs: str, train_chunks: list[int], cfg: RolloutConfig) -> dict:
    """An mse student's margin (distil.Student) with the least regret on the validation chunks, the student fitted on
    the other training chunks (held-out chunks never take part); a tie goes to the larger margin."""
    val_chunks = validation_chunks(train_chunks)
    fit_on = np.isin(data["chunk"], [c for c in train_chunks if c not in val_chunks])
    val = np.isin(data["chunk"], val_chunks)
    student = distil.fit(distil.design(data, inputs)[fit_on], adv[fit_on], inputs, cfg)
    regrets = {}
    for m in MARGINS:
        student.margin.fill_(m)
        regrets[m] = float(distil.regret(data["returns"][val], student.choose(distil.design(data, inputs)[val]), cfg).mean())
    best = min(MARGINS, key=lambda m: (regrets[m], -m))
    return dict(margin=best, validation_chunks=val_chunks, validation_regret=regrets)


def train(args):
    # the labels of the states these students drove to: A names --loss's student A (decision-A); a tag with its loss
    # (decision-A, mse-B: the committed mse round's B) names another loss's round
    daggers = [d.removeprefix("mse-") if d.startswith(("mse-", "decision-")) else distil.tagged(d, args.loss)
               for d in args.dagger]
    data, chunks = load_labels(args.scenario, args.actor_seed, args.out, daggers)
    cfg = RolloutConfig()
    held = held_out(data)
    if not held.any() or held.all():
        raise SystemExit(f"{len(chunks)} chunks: at least {HELD_OUT} are needed, one of them held out")
    train_chunks = sorted({int(c) for c in data["chunk"][~held]})
    val_chunks = validation_chunks(train_chunks)
    fit_chunks = train_chunks if args.loss == "mse" else [c for c in train_chunks if c not in val_chunks]
    if not fit_chunks:
        raise SystemExit(f"{len(chunks)} chunks: a student of loss {args.loss} needs training chunks beside the "
                         "validation ones")
    adv = distil.advantages(data["returns"], cfg)
    test = {k: v[held] for k, v in data.items()}
    val = np.isin(data["chunk"], val_chunks)
    out = students_dir(args.out, args.scenario, args.actor_seed, args.dagger, args.loss)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)

    decisive = distil.advantages(test["returns"], cfg).max(1) >= DECISIVE

    def scores(chosen):
        lost = distil.regret(test["returns"], chosen, cfg)
        return dict(agreement=float(np.mean(chosen == test["T"])), regret=float(lost.mean()),
                    decisive_agreement=float(np.mean(chosen[decisive] == test["T"][decisive])),
                    decisive_regret=float(lost[decisive].mean()))

    results, curve, how = {}, {}, {}  # how: an mse student's margin, or where a decision student stopped
    for inputs in args.students:
        x = distil.design(data, inputs)
        if args.loss == "mse":
            how[inputs] = choose_margin(data, adv, inputs, train_chunks, cfg)
        for share in CURVE:
            use = np.isin(data["chunk"], fit_chunks[:max(1, round(share * len(fit_chunks)))])
            if args.loss == "mse":
                student = distil.fit(x[use], adv[use], inputs, cfg)
                student.margin.fill_(how[inputs]["margin"])
            else:
                student, stop = distil.fit_decision(x[use], adv[use], inputs, cfg, (x[val], adv[val]))
            curve.setdefault(inputs, []).append(dict(cases=int(len({(c, k) for c, k in zip(data["chunk"][use],
                                                                                             data["case"][use])})),
                                                     decisions=int(use.sum()),
                                                     **scores(student.choose(distil.design(test, inputs)))))
        if args.loss == "decision":
            how[inputs] = dict(epoch=stop["epoch"], validation_chunks=val_chunks,
                               validation_regret=[round(r, 4) for r in stop["validation_regret"]])
        student.save(out / f"{inputs}.pt")
        chosen = student.choose(distil.design(test, inputs))
        results[inputs] = dict(curve[inputs][-1], gate=distil.gate(test["returns"], chosen, case_ids(test), cfg))
        print(f"student {inputs}: {results[inputs]}", flush=True)
    baseline = {"T = 2 always": scores(np.full(held.sum(), cfg.default_T)),
                "the teacher's most frequent T": scores(np.full(held.sum(), np.bincount(data["T"][~held]).argmax()))}
    (out / "students.json").write_text(json.dumps(dict(
        loss=args.loss, dagger=daggers, results=results, curve=curve, baseline=baseline,
        **{"margins" if args.loss == "mse" else "stopping": how}, train_chunks=train_chunks,
        validation_chunks=val_chunks, held_out_decisions=int(held.sum()), decisive_decisions=int(decisive.sum()),
        train_decisions=int((~held).sum())), indent=1))
    print(json.dumps(baseline))
    if {"A", "B"} <= set(results):
        print(f"the lower held-out regret of A and B: {lower_regret(out)}")


def held_out_choices(out: Path, scenario: str, actor_seed: int, loss: str, dagger: bool,
                     cache: dict | None = None) -> tuple[dict, dict]:
    """The held-out decisions of the labels a folder's students (students_dir) were trained with, and each student's
    T on them; ({}, {}) without students.json. cache: label folders already read (read_labels)."""
    students = students_dir(out, scenario, actor_seed, dagger, loss)
    if not (students / "students.json").exists():
        return {}, {}
    st = json.loads((students / "students.json").read_text())
    daggers = st.get("dagger", ["B"] if dagger else [])  # the committed mse round: student B drove
    data, _ = read_labels([folder(scenario, actor_seed, out, d) for d in (None, *daggers)], cache)
    test = {k: v[held_out(data)] for k, v in data.items()}
    return test, {name: distil.Student.load(students / f"{name}.pt").choose(distil.design(test, name))
                  for name in st["results"]}


def gates(out: Path, scenario: str, actor_seed: int, loss: str, dagger: bool, cache: dict | None = None) -> dict:
    """Each student of a folder through distil.gate on its held-out decisions (held_out_choices)."""
    test, chosen = held_out_choices(out, scenario, actor_seed, loss, dagger, cache)
    return {name: distil.gate(test["returns"], T, case_ids(test), RolloutConfig()) for name, T in chosen.items()}


def evaluate(args):
    out = students_dir(args.out, args.scenario, args.actor_seed, args.dagger, args.loss)
    todo, passed = [], None
    for inputs in args.students:
        student, dst = out / f"{inputs}.pt", out / f"eval-{inputs}.json"
        if not student.exists():
            raise SystemExit(f"no student {student}: run `train` first")
        if dst.exists():
            continue
        if not args.ungated:
            if passed is None:
                passed = gates(args.out, args.scenario, args.actor_seed, args.loss, args.dagger)
            if not (g := passed[inputs])["passes"]:
                print(f"student {inputs}: held-out regret {g['regret']:.3f} against T = 2 always's "
                      f"{g['default_regret']:.3f}, {g['diff']:+.3f} [{g['low']:+.3f}, {g['high']:+.3f}]: it does not "
                      "pass the gate, not evaluated (--ungated: evaluate it anyway)", flush=True)
                continue
        todo.append((inputs, student, dst))
    if not todo:
        return
    from table3 import commit, evaluate_policy  # bench/table3.py's
    for inputs, student, dst in todo:
        done = evaluate_policy(policy_path(args.scenario, args.actor_seed), args.scenario, "tarl", args.actor_seed,
                               ROOT / "runs" / "distil" / f"{out.name}-{inputs}", None, "--timing",
                               f"distilled={student}", "--eval-rows", "trained", workers=args.workers)
        if done is None:
            raise SystemExit(f"student {inputs}: the evaluation failed")
        dst.write_text(done.read_text())
        if args.commit:
            commit([dst], f"distil: student {inputs} of the {args.scenario} (actor seed {args.actor_seed}"
                          + f", loss {args.loss}" * (args.loss != "mse") + ", after DAgger" * bool(args.dagger)
                          + ") on the test cases")


PAIRED = (("TARL", "runs/{run}/eval.json", "tarl"), ("tarl-fixed-t", "runs/{run}/eval.json", "tarl-fixed-t"),
          ("tarl-random-t", "runs/{run}/eval.json", "tarl-random-t"),
          ("TARL's actor, T = 2", "retime/{run}-fixed2.json", "tarl"),
          ("TARL's actor, T random", "retime/{run}-random.json", "tarl"),
          ("the teacher (400 cases)", "rollout/{run}-rollout.json", "tarl"))  # {run}: the row's run of that seed
ABLATIONS = ("tarl-fixed-t", "tarl-random-t")  # the verdict's: Table 3's ablation rows, trained with that timing
ALPHA = 0.05
LABEL_SETS = re.compile(r"([a-z]+)-s(\d+)(?:-dagger-(.+))?")  # labels/SCENARIO-sSEED[-dagger-STUDENT]
STUDENT_SETS = re.compile(rf"([a-z]+)-s(\d+)(?:-({'|'.join(LOSSES)}))?(-dagger)?")  # SCENARIO-sSEED[-LOSS][-dagger]


def interval(r: dict, key: str = "mean") -> str:
    return f"{r[key]:+.3f} [{r['low']:+.3f}, {r['high']:+.3f}]"


def label_report(out: Path, cache: dict | None = None) -> list[str]:
    """The teacher's labels measured, per label folder: how reliable each candidate's label is, and what its choices
    gain in a future they were not made in."""
    cfg = RolloutConfig()
    others = [T for T in cfg.candidates if T != cfg.default_T]
    lines = ["## The teacher's labels", "",
             f"Per label folder, every decision. Reliability of T's label (its advantage over T = {cfg.default_T}, the "
             f"mean of K = {cfg.futures} futures): 1 - noise variance / total variance, the noise variance s^2 / K of "
             "the K per-future advantages averaged over decisions, the total the variance of the labels across "
             "decisions (distil.reliability). Replicated gain (distil.replicated_gain): for each of the K ways of "
             "holding out one future, the teacher's choice made from the other futures, scored in the held-out one as "
             f"its return minus T = {cfg.default_T}'s; per decision, the mean over the hold-outs. Confident: a choice "
             f"(one hold-out's) at least {DECISIVE:g} ahead of T = {cfg.default_T} in the futures it was made from; "
             "the others off T = 2 were less ahead there. 95 % intervals resample cases.", "",
             "| scenario | actor seed | labels | decisions (cases) | reliability T = "
             f"{' / '.join(map(str, others))} | replicated gain per decision [95 % CI] | confident choices: share, "
             "share of the gain | other choices off T = 2: share, gain per choice [95 % CI] |",
             "|---|---|---|---|---|---|---|---|"]
    found = sorted((m[1], int(m[2]), m[3] or "") for d in (out / "labels").glob("*")
                   if d.is_dir() and (m := LABEL_SETS.fullmatch(d.name)))
    for scenario, seed, drove in found:
        data, _ = read_labels([folder(scenario, seed, out, drove or None)], cache)
        rel = distil.reliability(data["returns"], cfg)
        gain, expected = distil.replicated_gain(data["returns"], cfg)  # (decisions, K)
        cases = case_ids(data)
        each = np.repeat(cases[:, None], gain.shape[1], axis=1)  # a choice's case
        confident, less = expected >= DECISIVE, (expected > 0) & (expected < DECISIVE)
        rest = f"{less.mean():.1%}, {interval(distil.case_bootstrap(gain[less], each[less]))}" if less.any() else "-"
        lines.append(f"| {scenario} | {seed} | {f'student {drove} drove (DAgger)' if drove else 'the teacher'} | "
                     f"{len(gain)} ({len(set(cases))}) | {' / '.join(f'{rel[T]:.2f}' for T in others)} | "
                     f"{interval(distil.case_bootstrap(gain.mean(axis=1), cases))} | {confident.mean():.1%}, "
                     f"{gain[confident].sum() / gain.sum():.0%} | {rest} |")
    return lines + [""] if found else []


def gate_report(out: Path, found: list[tuple], cache: dict | None = None) -> list[str]:
    """Every student of every folder through the gate, and the lower of A and B in each folder."""
    cfg = RolloutConfig()
    lines = ["## The gate: held-out regret against T = 2 always", "",
             "A student is put on the test cases only if its held-out regret (mean per decision) is below T = 2 "
             "always's, the case-bootstrap 95 % interval of the difference excluding 0 (distil.gate). Held out: the "
             "chunks K % 5 == 4 of the labels it was trained with (before DAgger, the same decisions for both losses). "
             "Loss mse: the committed students (every candidate's advantage, a margin); decision: trained for the "
             "choice they make, stopped early on validation chunks.", "",
             "| scenario | actor seed | loss | DAgger | student | held-out decisions (cases) | regret | T = 2 always | "
             "student - T = 2 [95 % CI] | gate |", "|---|---|---|---|---|---|---|---|---|---|"]
    lower = []
    for scenario, seed, loss, dagger in found:
        test, chosen = held_out_choices(out, scenario, seed, loss, dagger, cache)
        when = "after" if dagger else "before"
        for name, T in chosen.items():
            g = distil.gate(test["returns"], T, case_ids(test), cfg)
            lines.append(f"| {scenario} | {seed} | {loss} | {when} | {name} | {g['decisions']} ({g['cases']}) | "
                         f"{g['regret']:.3f} | {g['default_regret']:.3f} | {interval(g, 'diff')} | "
                         f"{'passes' if g['passes'] else 'fails'} |")
        if {"A", "B"} <= set(chosen):
            a, b = (distil.regret(test["returns"], chosen[n], cfg) for n in "AB")
            lower.append(f"| {scenario} | {seed} | {loss} | {when} | "
                         f"{lower_regret(students_dir(out, scenario, seed, dagger, loss))} | {a.mean():.3f} / "
                         f"{b.mean():.3f} | {interval(distil.case_bootstrap(a - b, case_ids(test)))} |")
    if lower:
        lines += ["", "The lower held-out regret of A and B (lower_regret: before DAgger the student that drives the "
                  "round, after it the student of record):", "",
                  "| scenario | actor seed | loss | DAgger | lower | regret A / B | A - B [95 % CI] |",
                  "|---|---|---|---|---|---|---|", *lower]
    return lines + [""]


# The test registered on 2026-12-07 before any of its labels was used (results/distil/README.md): the scenario, its
# actor seeds, the row each student of record is paired with, the level (0.025: a second try may share 0.05)
REGISTERED = dict(scenario="intersection", seeds=(0, 3, 4), row="tarl-random-t", alpha=0.025, ahead=2)


def registered_test(out: Path, runs: Path = ROOT / "results" / "runs") -> list[str]:
    """The registered test: per seed, the student of record (lower_regret of the decision students after their DAgger
    round, SCENARIO-sK-decision-dagger) against that seed's REGISTERED row on the same test cases; it passes if the
    exact McNemar test pooled over the seeds' cases has p < alpha, the student ahead, and it is ahead on at least
    `ahead` seeds. Empty until every seed's student of record has played."""
    from analysis.compare import read_row
    from analysis.paired import p_text
    from rollout_ceiling import paired
    scenario, row, rng = REGISTERED["scenario"], REGISTERED["row"], np.random.default_rng(0)
    mine, theirs, each, lines = [], [], [], []
    for k in REGISTERED["seeds"]:
        folder = students_dir(out, scenario, k, True, "decision")
        name = lower_regret(folder) if (folder / "students.json").exists() else None
        if name is None or not (folder / f"eval-{name}.json").exists():
            return []
        mine.append(read_row(folder / f"eval-{name}.json"))
        theirs.append(read_row(runs / experiment.run_name(scenario, row, k) / "eval.json", row))
        each.append(r := paired(mine[-1], theirs[-1], rng))
        lines.append(f"| {k} | {name} | {r['mine']:.3f} | {r['other']:.3f} | {r['only_mine']} / {r['only_other']} | "
                     f"{p_text(r['p'])} |")
    r = paired(mine, theirs, rng)
    ahead = sum(x["only_mine"] > x["only_other"] for x in each)
    passes = r["p"] < REGISTERED["alpha"] and r["only_mine"] > r["only_other"] and ahead >= REGISTERED["ahead"]
    return ["## The test registered on 2026-12-07", "",
            f"Each seed's student of record (after its DAgger round) against that seed's `{row}` on its "
            f"{scenario}'s test cases; pooled exact McNemar p < {REGISTERED['alpha']}, the student ahead, and ahead "
            f"on at least {REGISTERED['ahead']} of {len(REGISTERED['seeds'])} seeds.", "",
            f"| actor seed | student of record | its success | `{row}` | student only / it only arrives | McNemar p |",
            "|---|---|---|---|---|---|", *lines,
            f"| pooled | | {r['mine']:.3f} | {r['other']:.3f} | {r['only_mine']} / {r['only_other']} | {p_text(r['p'])} |",
            "", f"Ahead on {ahead} of {len(REGISTERED['seeds'])} seeds: the students of record **"
            + ("pass" if passes else "fail") + "** the registered test.", ""]


def report(args) -> str:
    from analysis.compare import read_row
    from analysis.paired import p_text
    from rollout_ceiling import paired
    head = ["# A timing taught by a privileged teacher", "",
             "Built by `python bench/distillation.py report` (bench/distillation.py's docstring: how). Regret: the "
             "return (Eq. (31), to the episode's end) a choice loses per decision against the teacher's best "
             "candidate, on held-out cases; agreement: the share of held-out decisions where it picks the teacher's T.",
             ""]
    lines = []  # each scenario's and seed's sections, after the glance tables
    found = sorted({(m[1], int(m[2]), m[3] or "mse", bool(m[4])) for d in args.out.glob("*-s*")
                    if (m := STUDENT_SETS.fullmatch(d.name)) and m[1] in SCENARIOS},
                   key=lambda f: (SCENARIOS.index(f[0]), f[1], -LOSSES.index(f[2]), f[3]))
    glance = ["## Every student against the rule", "",
              "| scenario | actor seed | loss | DAgger | student | success | the better ablation row | student only / "
              "it only arrives | McNemar p | verdict |", "|---|---|---|---|---|---|---|---|---|---|"]
    for scenario, seed, loss, dagger in found:
        out = students_dir(args.out, scenario, seed, dagger, loss)
        if not (out / "students.json").exists():
            continue
        st = json.loads((out / "students.json").read_text())
        lines += [f"## {scenario}, actor seed {seed}" + ", students trained for their decision" * (loss == "decision")
                  + (", after one DAgger round" if dagger else ""), "",
                  f"{st['train_decisions']} training and {st['held_out_decisions']} held-out decisions "
                  f"(chunks {', '.join(map(str, st['train_chunks']))} train"
                  + (f"; {', '.join(map(str, st['validation_chunks']))} validate" if "validation_chunks" in st else "")
                  + ").", "",
                  f"Decisive: the {st['decisive_decisions']} held-out decisions where some T beats T = 2 by at least "
                  f"{DECISIVE:g} (an outcome at stake).", "",
                  "| choice | agreement | regret per decision | decisive: agreement | decisive: regret | "
                  "regret by training cases |", "|---|---|---|---|---|---|"]
        for name, r in [*st["baseline"].items(), *st["results"].items()]:
            curve = ", ".join(f"{c['cases']}: {c['regret']:.3f}" for c in st["curve"].get(name, []))
            who = name
            if name in st["results"]:
                how = (f"margin {st['margins'][name]['margin']:g}" if "margins" in st
                       else f"stopped at epoch {st['stopping'][name]['epoch']}")
                who = f"student {name} ({', '.join(distil.groups(name))}; {how})"
            lines.append(f"| {who} | {r['agreement']:.3f} | {r['regret']:.3f} | {r['decisive_agreement']:.3f} | "
                         f"{r['decisive_regret']:.3f} | {curve or '-'} |")
        lines += [""]
        rng = np.random.default_rng(0)
        for name in st["results"]:
            if not (out / f"eval-{name}.json").exists():
                continue
            mine = read_row(out / f"eval-{name}.json")
            lines += [f"Student {name} on the test cases: success {mine['success_rate']['mean']:.3f}, collision "
                      f"{mine['collision_rate']['mean']:.3f}, timeout {mine['timeout_rate']['mean']:.3f}.", "",
                      "| against | world | its success | student only / it only arrives | McNemar p | student - it "
                      "[95 % CI, cases resampled] |", "|---|---|---|---|---|---|"]
            res = {}
            for label, path, algo in PAIRED:
                file = ROOT / "results" / path.format(run=experiment.run_name(scenario, algo, seed))
                if file.exists():
                    res[label] = r = paired(mine, read_row(file, algo), rng)
                    lines.append(f"| {label} | {experiment.read_eval(file)['world']} | {r['other']:.3f} | "
                                 f"{r['only_mine']} / {r['only_other']} | {p_text(r['p'])} | {r['diff']:+.3f} "
                                 f"[{r['low']:+.3f}, {r['high']:+.3f}] |")
            if all(a in res for a in ABLATIONS):
                best = max(ABLATIONS, key=lambda a: res[a]["other"])
                r = res[best]
                verdict = "passes" if r["diff"] > 0 and r["p"] < ALPHA else "does not pass"
                if loss == "decision":  # registered apart: the pooled test above, or (the roundabout) no verdict at all
                    verdict = "the pooled test above" if scenario == REGISTERED["scenario"] else "secondary, no verdict"
                    lines += ["", f"Against the better ablation row here ({best}, {r['other']:.3f}): {r['diff']:+.3f}, "
                              f"p {p_text(r['p'])}; {verdict}.", ""]
                else:
                    lines += ["", f"The pre-registered test (the better ablation row here is {best}, {r['other']:.3f}): "
                              f"student {name} **{verdict}** ({r['diff']:+.3f}, p {p_text(r['p'])}).", ""]
                glance.append(f"| {scenario} | {seed} | {loss} | {'after' if dagger else 'before'} | {name} | "
                              f"{r['mine']:.3f} | {best} {r['other']:.3f} | {r['only_mine']} / {r['only_other']} | "
                              f"{p_text(r['p'])} | {verdict} |")
    cache = {}  # label folders read, for both
    text = "\n".join(head + registered_test(args.out) + label_report(args.out, cache) + gate_report(args.out, found, cache)
                     + glance + [""] + lines) + "\n"
    (args.out / "summary.md").write_text(text)
    return text


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    for name in ("label", "train", "evaluate", "report"):
        s = sub.add_parser(name)
        if name != "report":  # report: every scenario and actor seed with students
            s.add_argument("--scenario", choices=SCENARIOS, required=True)
            s.add_argument("--actor-seed", type=int, default=0, help="whose committed TARL actor (results/runs)")
        s.add_argument("--out", type=Path, default=OUT, help="where the labels and students go")
    lab = sub.choices["label"]
    lab.add_argument("--cases", type=int, default=1000, help="cases to label, in chunks")
    lab.add_argument("--chunk", type=int, default=20, help="cases per chunk (one file, one commit)")
    lab.add_argument("--commit", action="store_true", help="git commit each chunk as it finishes")
    lab.add_argument("--student", type=Path,
                     help="DAgger: this student drives, the teacher labels (labels/...-dagger-X); a folder of "
                          "students: its A or B of lower held-out regret")
    lab.add_argument("--first-chunk", type=int, default=0, help="the first chunk's number (its seed: LABEL_SEED + it)")
    for name in ("train", "evaluate"):
        sub.choices[name].add_argument("--students", nargs="+", default=list(distil.INPUTS),
                                       help="input sets: A, B, C, or one less a group (C-routes)")
        sub.choices[name].add_argument("--dagger", nargs="+", default=[], metavar="STUDENT",
                                       help="also the labels of the states these students (of --loss; or tagged with "
                                            "theirs: decision-A, mse-B) drove to (label --student); the students go "
                                            "to SCENARIO-sSEED[-LOSS]-dagger")
        sub.choices[name].add_argument("--loss", choices=LOSSES, default=LOSSES[0],
                                       help="decision: trained for the choice, stopped early (SCENARIO-sSEED-decision);"
                                            " mse: every candidate's advantage and a margin (the committed students)")
    sub.choices["evaluate"].add_argument("--workers", type=int, default=1, help="evaluation processes")
    sub.choices["evaluate"].add_argument("--commit", action="store_true", help="git commit each student's eval.json")
    sub.choices["evaluate"].add_argument("--ungated", action="store_true",
                                         help="also the students whose held-out regret does not pass the gate")
    args = p.parse_args(argv)
    if args.command == "label":
        if args.cases < 1 or args.chunk < 1 or args.first_chunk < 0:
            p.error("--cases and --chunk are at least 1, --first-chunk at least 0")
        if args.student is not None and not (args.student.is_file() or (args.student / "students.json").is_file()):
            p.error(f"--student {args.student}: no such student file or folder of students")
        torch.set_num_threads(1)
        label(args)
    elif args.command == "report":
        print(report(args))
    else:
        for inputs in args.students:
            try:
                distil.groups(inputs)
            except ValueError as e:
                p.error(str(e))
        (train if args.command == "train" else evaluate)(args)


if __name__ == "__main__":
    main()
