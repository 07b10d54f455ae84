"""``python -m backend.cli``: the commands without the two that start the studio (how the studio starts node
agents: a process boundary that needs no ``studio`` import)."""

import sys

from backend.cli import main

sys.exit(main())
