"""``hydrowatch web``: the live fleet web page (services.web)."""

import services.web as service
from hydrowatch.bus.service import command_run

NAME = "web"
HELP = service.HELP
add_arguments = service.add_arguments
run = command_run(service.run)
