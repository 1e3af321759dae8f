"""Plausible wrong answers the checker must catch, one mistake each (the rest is the solution's).

Each file says in CHECKER_SAYS a part of the message the checker gives on it; tests/test_exercises.py checks
that it does. The checker is run on them with: python -m exercises.check N --file exercises/wrong/<file>.
"""
