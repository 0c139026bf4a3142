"""``python -m sb3_gcrl.compare`` = ``sb3-gcrl compare``."""

import sys

from sb3_gcrl.compare.cli import main

if __name__ == "__main__":
    sys.exit(main())
