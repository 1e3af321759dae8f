"""`python -m exercises.paired`, the labs' command: it runs analysis/paired.py, where the project's paired statistics live
(bench/ uses them too). Read analysis/paired.py."""
import sys

from analysis.paired import main

if __name__ == "__main__":
    sys.exit(main())
