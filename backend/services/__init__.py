"""What the front-ends (API, studio, CLI) call; every one of them reaches the devices through here."""

import backend.sim.devices  # noqa: F401  (registers the simulated drivers and endpoints; drivers never import sim)
