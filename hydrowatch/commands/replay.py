"""``hydrowatch replay``: the replay service (services.replay)."""

import services.replay as service
from hydrowatch.bus.service import command_run

NAME = "replay"
HELP = service.HELP
add_arguments = service.add_arguments
run = command_run(service.run)
