import sys

from services.recorder import main

sys.exit(main())
