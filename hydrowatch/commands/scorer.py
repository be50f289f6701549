"""``hydrowatch scorer``: the scorer service (services.scorer)."""

import services.scorer as service
from hydrowatch.bus.service import command_run

NAME = "scorer"
HELP = service.HELP
add_arguments = service.add_arguments
run = command_run(service.run)
