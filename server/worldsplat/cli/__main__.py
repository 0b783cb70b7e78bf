"""`python -m worldsplat.cli ...` is `worldsplat ...`."""

import sys

from worldsplat.cli import main

sys.exit(main())
