"""Exercises beside the paper: implement a piece of it, then check it (EXERCISES.md).

    python -m exercises.check 1              # check exercises/ex1_timing.py
    python -m exercises.check 1 --solution   # the same check on exercises/solutions/ex1_timing.py
    python -m exercises.check 1 --in-vivo    # its functions driving the shipped policy (in_vivo.py)
    python -m exercises.bughunt              # the bug hunt's run
    python -m exercises.compare A/eval.json B/eval.json    # two evaluations case by case
    python -m exercises.paired --scenario roundabout tarl sac-lag    # paired statistics, no simulation

ex1_timing.py .. ex5_timing_target.py are the stubs a student fills in (TODO(student)), solutions/ the
reference answers, wrong/ plausible wrong answers the checker must catch, data/ the stored answers
(make_data.py: exN.npz, and in_vivo.json, the project's own run of the in-vivo cases),
bughunt_observe.py the bug hunt.
"""
