"""``python -m vehicle_sim.independent``: see :mod:`vehicle_sim.independent`."""

import sys

from vehicle_sim.independent.suite import main

sys.exit(main())
