"""`python -m sim.cli` is `rheo`."""
import sys

from sim.cli import main

sys.exit(main())
