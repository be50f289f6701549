import sys

from services.trainer import main

sys.exit(main())
