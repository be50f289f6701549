"""``hydrowatch plant``: the plant service (services.plant)."""

import services.plant as service
from hydrowatch.bus.service import command_run

NAME = "plant"
HELP = service.HELP
add_arguments = service.add_arguments
run = command_run(service.run)
