"""``hydrowatch trainer``: the trainer service (services.trainer)."""

import services.trainer as service
from hydrowatch.bus.service import command_run

NAME = "trainer"
HELP = service.HELP
add_arguments = service.add_arguments
run = command_run(service.run)
