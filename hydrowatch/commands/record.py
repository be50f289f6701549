"""``hydrowatch record``: the recorder service (services.recorder)."""

import services.recorder as service
from hydrowatch.bus.service import command_run

NAME = "record"
HELP = service.HELP
add_arguments = service.add_arguments
run = command_run(service.run)
