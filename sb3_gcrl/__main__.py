import sys

from sb3_gcrl.cli import main

if __name__ == "__main__":
    sys.exit(main())
