"""Exercises beside the paper: implement a piece of it, then check it (EXERCISES.md).

    python -m exercises.check 1              # check exercises/ex1_timing.py
    python -m exercises.check 1 --solution   # the same check on exercises/solutions/ex1_timing.py

ex1_timing.py .. ex5_timing_target.py are the stubs a student fills in (TODO(student)), solutions/ the
reference answers, wrong/ plausible wrong answers the checker must catch, data/ the stored answers
(make_data.py), bughunt_observe.py the bug hunt.
"""
