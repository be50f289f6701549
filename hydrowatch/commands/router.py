"""``hydrowatch router``: a zenoh router for the services to join as clients (services.router)."""

import services.router as service
from hydrowatch.bus.service import command_run

NAME = "router"
HELP = service.HELP
add_arguments = service.add_arguments
run = command_run(service.run)
