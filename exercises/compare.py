"""`python -m exercises.compare`, the labs' command: it runs analysis/compare.py, where the project's paired statistics live
(bench/ uses them too). Read analysis/compare.py."""
import sys

from analysis.compare import main

if __name__ == "__main__":
    sys.exit(main())
