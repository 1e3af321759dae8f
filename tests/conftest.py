"""The tests import the project's modules from its root (tarl, world, ...) and bench/'s scripts by name (table3,
slurm, ...), as those scripts do themselves; run them from anywhere: python -m pytest -q."""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / "bench"):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))
